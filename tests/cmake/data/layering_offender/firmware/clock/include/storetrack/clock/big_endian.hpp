// Fixture for test_layering_check_names_offender: a header a firmware library publishes.
