// Fixture for test_layering_check_names_offender: a host source reaching into the firmware wing.
#include "storetrack/clock/big_endian.hpp"
