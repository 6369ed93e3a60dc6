#include "stats.hpp"

#include <cinttypes>
#include <cstdio>
#include <fstream>

namespace storetrack::hostapp {
namespace {

nlohmann::json decode_counters_json(const msg::DecodeCounters& c) {
  nlohmann::json j = nlohmann::json::object();
  for (std::size_t i = 1; i < msg::kNumDecodeErrors; ++i)
    j[msg::to_string(static_cast<msg::DecodeError>(i))] = c.by_error[i];
  return j;
}

nlohmann::json udp_stats_json(const ingest::UdpReceiver& udp) {
  const auto& uc = udp.counters();
  return {{"datagrams", uc.datagrams},
          {"bytes", uc.bytes},
          {"decoded", uc.decoded},
          {"receive_errors", uc.receive_errors},
          {"datagram_seq_gaps", uc.datagram_seq_gaps},
          {"spoofed_source", uc.spoofed_source},
          {"kernel_drops", uc.kernel_drops},
          {"budget_exhausted", uc.budget_exhausted},
          {"receive_buffer_requested_bytes", uc.receive_buffer_requested_bytes},
          {"receive_buffer_bytes", uc.receive_buffer_bytes},
          {"kernel_filter_sources", uc.kernel_filter_sources},
          {"decode_errors", decode_counters_json(uc.decode_errors)},
          {"last_refused_version", ingest::describe(uc.last_refused_version)}};
}

nlohmann::json can_stats_json(const std::vector<std::unique_ptr<ingest::CanFdReceiver>>& cans,
                              const std::vector<std::string>& interfaces) {
  nlohmann::json can_json = nlohmann::json::array();
  for (std::size_t i = 0; i < cans.size(); ++i) {
    const auto& c = cans[i]->counters();
    const auto& r = cans[i]->reassembly_counters();
    can_json.push_back({{"interface", interfaces[i]},
                        {"frames", c.frames},
                        {"classic_or_bad_frames", c.classic_or_bad_frames},
                        {"decoded", c.decoded},
                        {"receive_errors", c.receive_errors},
                        {"kernel_drops", c.kernel_drops},
                        {"budget_exhausted", c.budget_exhausted},
                        {"decode_errors", decode_counters_json(c.decode_errors)},
                        {"last_refused_version", ingest::describe(c.last_refused_version)},
                        {"reassembly",
                         {{"completed", r.completed},
                          {"duplicates", r.duplicates},
                          {"crc_errors", r.crc_errors},
                          {"timeouts", r.timeouts},
                          {"evictions", r.evictions},
                          {"fragments_lost", r.fragments_lost}}}});
  }
  return can_json;
}

nlohmann::json aligner_stats_json(const ingest::ExposureAligner& aligner) {
  const auto& ac = aligner.counters();
  return {{"observations_in", ac.observations_in},
          {"observations_used", ac.observations_used},
          {"exposures_complete", ac.exposures_complete},
          {"exposures_partial_timeout", ac.exposures_partial_timeout},
          {"exposures_partial_overflow", ac.exposures_partial_overflow},
          {"exposures_dropped_too_few_cameras", ac.exposures_dropped_too_few_cameras},
          {"exposures_dropped_numbering_unknown", ac.exposures_dropped_numbering_unknown},
          {"dropped_unknown_camera", ac.dropped_unknown_camera},
          {"dropped_spoofed", ac.dropped_spoofed},
          {"dropped_invalid", ac.dropped_invalid},
          {"dropped_time_out_of_range", ac.dropped_time_out_of_range},
          {"dropped_duplicate", ac.dropped_duplicate},
          {"dropped_late", ac.dropped_late},
          {"dropped_time_mismatch", ac.dropped_time_mismatch},
          {"dropped_quarantined", ac.dropped_quarantined},
          {"dropped_too_few_cameras", ac.dropped_too_few_cameras},
          {"dropped_numbering_unknown", ac.dropped_numbering_unknown},
          {"sequence_offset_changes", ac.sequence_offset_changes},
          {"sequence_restarts", ac.sequence_restarts}};
}

nlohmann::json camera_stats_json(const ingest::ExposureAligner& aligner,
                                 const std::vector<int>& camera_ids) {
  nlohmann::json cams = nlohmann::json::array();
  for (std::size_t i = 0; i < camera_ids.size(); ++i) {
    const auto& c = aligner.camera_counters()[i];
    cams.push_back({{"camera_id", camera_ids[i]},
                    {"received", c.received},
                    {"used", c.used},
                    {"missing", c.missing},
                    {"late", c.late},
                    {"duplicate", c.duplicate},
                    {"time_mismatch", c.time_mismatch},
                    {"spoofed", c.spoofed},
                    {"quarantined", c.quarantined},
                    {"offset_changes", c.offset_changes},
                    {"sequence_offset", c.sequence_offset}});
  }
  return cams;
}

nlohmann::json identifier_stats_json(const pipeline::ExposureProcessor& processor) {
  const auto& ic = processor.matcher().counters();
  return {{"matcher", "host/match MarkMatcher"},
          {"exposures", ic.exposures},
          {"observations", ic.observations},
          {"identified", ic.identified},
          {"ambiguous", ic.ambiguous_observation + ic.ambiguous_mark},
          {"ambiguous_observation", ic.ambiguous_observation},
          {"ambiguous_mark", ic.ambiguous_mark},
          {"unmatched", ic.unmatched},
          {"unknown_camera", ic.unknown_camera},
          {"bad_observation", ic.bad_observation},
          {"fallback_sigma", ic.fallback_sigma},
          {"rejected_by_flags", ic.rejected_by_flags},
          {"undistort_failed", ic.undistort_failed},
          {"epipolar_outlier", ic.epipolar_outlier},
          {"epipolar_rejected", ic.epipolar_rejected},
          {"layout_rejected", ic.layout_rejected},
          {"single_view", ic.single_view},
          {"acquisitions", ic.acquisitions},
          {"duplicate_camera", ic.duplicate_camera},
          {"lost_body", ic.lost_body},
          {"reacquisition_attempted", ic.reacquisition_attempted},
          {"reacquisition_accepted", ic.reacquisition_accepted},
          {"reacquisition_ambiguous", ic.reacquisition_ambiguous},
          {"reacquisition_inconsistent", ic.reacquisition_inconsistent},
          {"reacquisition_too_few_marks", ic.reacquisition_too_few_marks},
          {"reacquisition_outside_region", ic.reacquisition_outside_region},
          {"reacquisition_deferred", ic.reacquisition_deferred},
          {"duplicate_id", ic.duplicate_id},
          {"given_ids_of_no_body", ic.given_ids_of_no_body},
          {"triangulation_failed", ic.triangulation_failed}};
}

nlohmann::json processor_stats_json(const pipeline::ExposureProcessor& processor) {
  const auto& pc = processor.counters();
  return {{"exposures", pc.exposures},
          {"unknown_camera", pc.unknown_camera},
          {"time_sigma_unknown", pc.time_sigma_unknown},
          {"id_out_of_range", pc.id_out_of_range},
          {"too_few_cameras", pc.too_few_cameras},
          {"triangulation_failed", pc.triangulation_failed},
          {"marks_excluded", pc.marks_excluded},
          {"pose_failed", pc.pose_failed},
          {"degenerate_geometry", pc.degenerate_geometry},
          {"single_view_poses", pc.single_view_poses},
          {"single_view_rejected", pc.single_view_rejected}};
}

// The four CSVs' rows and failures, the same keys under "recording" and in "outputs".
nlohmann::json csv_counters_json(const RecordingCounters& rc) {
  return {{"csv_rows", rc.csv_rows},
          {"csv_write_errors", rc.csv_write_errors},
          {"csv_close_errors", rc.csv_close_errors},
          {"marks_csv_write_errors", rc.marks_csv_write_errors},
          {"marks_csv_close_errors", rc.marks_csv_close_errors},
          {"rigid_csv_write_errors", rc.rigid_csv_write_errors},
          {"rigid_csv_close_errors", rc.rigid_csv_close_errors},
          {"clearance_csv_write_errors", rc.clearance_csv_write_errors},
          {"clearance_csv_close_errors", rc.clearance_csv_close_errors}};
}

}  // namespace

nlohmann::json recording_stats_json(const RecordingWriter& recording,
                                    const std::string& requested_ch10_path) {
  const RecordingCounters rc = recording.counters();
  const auto& cc = recording.ch10().counters();
  nlohmann::json ch10 = {{"requested_path", requested_ch10_path},
                         {"files", recording.ch10().files()},
                         {"files_opened", cc.files_opened},
                         {"numbered_instead_of_existing", cc.numbered_instead_of_existing},
                         {"continuation_files", cc.continuation_files},
                         {"packets_written", cc.packets_written},
                         {"messages_written", cc.messages_written},
                         {"messages_dropped", cc.messages_dropped},
                         {"packets_dropped", cc.packets_dropped},
                         {"write_errors", cc.write_errors},
                         {"sync_errors", cc.sync_errors},
                         {"truncations", cc.truncations},
                         {"truncate_errors", cc.truncate_errors},
                         {"close_errors", cc.close_errors},
                         {"directory_sync_errors", cc.directory_sync_errors},
                         {"open_errors", cc.open_errors},
                         {"samples_out_of_order", cc.samples_out_of_order},
                         {"input_packets", cc.input_packets},
                         {"raw_packets", cc.raw_packets},
                         {"raw_messages_written", cc.raw_messages_written},
                         {"raw_bytes_written", cc.raw_bytes_written},
                         {"raw_packets_dropped", cc.raw_packets_dropped},
                         {"raw_messages_dropped", cc.raw_messages_dropped},
                         {"raw_refused", cc.raw_refused}};
  nlohmann::json out = {{"queue",
                         {{"max_items", RecordingWriter::kQueueItems},
                          {"max_text_bytes", RecordingWriter::kQueueTextBytes},
                          {"items_queued", rc.items_queued},
                          {"items_dropped_queue_full", rc.items_dropped_queue_full},
                          {"max_depth_items", rc.queue_max_items},
                          {"max_depth_text_bytes", rc.queue_max_text_bytes}}},
                        {"chapter10", ch10},
                        {"csv_files",
                         {{"csv", recording.csv_path()},
                          {"marks_csv", recording.marks_csv_path()},
                          {"rigid_csv", recording.rigid_csv_path()},
                          {"clearance_csv", recording.clearance_csv_path()}}},
                        {"ch10_sample_write_errors", rc.ch10_sample_write_errors},
                        {"raw_observations",
                         {{"enabled", recording.wants_raw()},
                          {"max_queue_items", RecordingWriter::kRawQueueItems},
                          {"max_queue_bytes", RecordingWriter::kRawQueueBytes},
                          {"queued", rc.raw_queued},
                          {"dropped_queue_full", rc.raw_dropped_queue_full},
                          {"dropped_queue_bytes", rc.raw_dropped_queue_bytes},
                          {"max_depth_items", rc.raw_queue_max_items},
                          {"write_errors", rc.raw_write_errors},
                          {"packets_written", cc.raw_packets},
                          {"messages_written", cc.raw_messages_written},
                          {"packets_dropped", cc.raw_packets_dropped},
                          {"messages_dropped", cc.raw_messages_dropped}}}};
  out.update(csv_counters_json(rc));
  return out;
}

nlohmann::json outputs_stats_json(const output::InetxSender& inetx,
                                  const RecordingWriter& recording) {
  const auto& cc = recording.ch10().counters();
  const RecordingCounters rc = recording.counters();
  // One key per output and kind of failure (docs/fti-output.md, "Counters"); the details are
  // under "recording".
  nlohmann::json out = {
      {"inetx_sent", inetx.counters().packets_sent},
      {"inetx_send_errors", inetx.counters().send_errors},
      {"ch10_packets", cc.packets_written},
      {"ch10_messages", cc.messages_written},
      {"ch10_time_packets", cc.time_packets},
      {"ch10_bytes", cc.bytes_written},
      {"ch10_write_errors", cc.write_errors},
      {"ch10_sync_errors", cc.sync_errors},
      {"ch10_close_errors", cc.close_errors},
      {"ch10_messages_dropped", cc.messages_dropped},
      {"ch10_raw_messages", cc.raw_messages_written},
      {"ch10_raw_messages_dropped",
       cc.raw_messages_dropped + rc.raw_dropped_queue_full + rc.raw_dropped_queue_bytes},
      {"file_queue_dropped", rc.items_dropped_queue_full},
      {"file_queue_max_depth", rc.queue_max_items}};
  out.update(csv_counters_json(rc));
  return out;
}

nlohmann::json clearance_json(const clearance::SampleClearance& clearance) {
  const clearance::ClearanceCounters& c = clearance.counters();
  nlohmann::json parts = nlohmann::json::array();
  for (std::size_t i = 0; i < clearance.model().aircraft_parts(); ++i)
    parts.push_back(std::string(clearance.model().aircraft_part_name(i)));
  return {{"aircraft_parts", parts},
          {"alarm_threshold_m", clearance.alarm_threshold_m()},
          {"samples_evaluated", c.samples_evaluated},
          {"alarm_samples", c.alarm_samples},
          {"alarm_episodes", c.alarm_episodes}};
}

nlohmann::json calibration_health_json(const pipeline::CalibrationHealthGuard& guard) {
  static constexpr const char* kModes[] = {"flag", "correct", "exclude"};
  const auto& mon = guard.monitor();
  const auto& gc = guard.counters();
  nlohmann::json cams = nlohmann::json::array();
  nlohmann::json unmonitored = nlohmann::json::array();
  for (const pipeline::CameraHealth& h : mon.cameras()) {
    nlohmann::json c = {{"camera_id", h.camera_id}, {"baseline_done", h.baseline_done},
                        {"monitored", h.monitored}, {"pylon_marks", h.pylon_marks},
                        {"moved", h.moved},         {"windows_tested", h.windows_tested},
                        {"alarms", h.alarms},       {"last_statistic", h.last_statistic}};
    if (h.moved) {
      // The latest alarm's estimate (left perturbation of T_c_w, camera frame) and its sigmas.
      const geometry::Vec6 sigma = h.motion_cov.diagonal().cwiseSqrt();
      c["first_alarm_exposure"] = h.first_alarm_exposure;
      c["motion_rotation_rad"] = {h.motion(0), h.motion(1), h.motion(2)};
      c["motion_translation_m"] = {h.motion(3), h.motion(4), h.motion(5)};
      c["u_motion_rotation_rad"] = {sigma(0), sigma(1), sigma(2)};
      c["u_motion_translation_m"] = {sigma(3), sigma(4), sigma(5)};
    }
    if (h.baseline_done && !h.monitored) unmonitored.push_back(h.camera_id);
    cams.push_back(std::move(c));
  }
  return {{"mode", kModes[static_cast<int>(guard.mode())]},
          {"threshold", mon.threshold()},
          {"window_exposures", mon.config().window_exposures},
          {"false_alarm_probability", mon.config().false_alarm_probability},
          {"samples_flagged", gc.samples_flagged},
          {"corrections", gc.corrections},
          {"exposures_excluding", gc.exposures_excluding},
          {"unmonitored_cameras", unmonitored},
          {"cameras", cams}};
}

nlohmann::json host_stats_json(const StatsSources& s) {
  nlohmann::json stats;
  stats["exposures_processed"] = s.totals.exposures;
  // exposures_processed = samples_written + every samples_withheld reason (sample_gate.hpp)
  stats["samples_written"] = s.totals.samples_written;
  stats["samples_withheld"] = {
      {"no_camera_used", s.totals.withheld.no_camera_used},
      {"fewer_cameras_than_min_cameras", s.totals.withheld.fewer_cameras_than_min}};
  stats["valid_samples"] = s.totals.valid_samples;
  stats["wall_time_s"] = s.wall_time_s;
  stats["udp"] = udp_stats_json(s.udp);
  stats["can"] = can_stats_json(s.cans, s.cfg.can_interfaces);
  stats["aligner"] = aligner_stats_json(s.aligner);
  stats["cameras"] = camera_stats_json(s.aligner, s.cfg.aligner.camera_ids);
  stats["identifier"] = identifier_stats_json(s.processor);
  stats["processor"] = processor_stats_json(s.processor);
  const auto& tc = s.processor.pose_tracker().counters();
  stats["pose_tracker"] = {{"solved", tc.solved},
                           {"extrapolated", tc.extrapolated},
                           {"not_extrapolated", tc.not_extrapolated},
                           {"extrapolated_in_release_zone", tc.extrapolated_in_release_zone}};
  stats["outputs"] = outputs_stats_json(s.inetx, s.recording);
  stats["recording"] = recording_stats_json(s.recording, s.cfg.ch10_path);
  const LoopTotals& t = s.totals;
  stats["latency"] = {
      {"last_observation_to_inetx_complete_exposures", t.latency_complete.to_json()},
      {"last_observation_to_inetx_all_exposures", t.latency_all.to_json()},
      {"processing_per_exposure", t.latency_processing.to_json()}};
  stats["unit_health_messages"] = t.health_messages;
  nlohmann::json health = nlohmann::json::object();
  for (const auto& [unit, h] : t.unit_health)
    health[std::to_string(unit)] = h;
  stats["unit_health"] = health;
  if (s.health) stats["calibration_health"] = calibration_health_json(*s.health);
  if (s.clearance) stats["clearance"] = clearance_json(*s.clearance);
  return stats;
}

void print_summary(const StatsSources& s) {
  const auto& ac = s.aligner.counters();
  const auto& ic = s.processor.matcher().counters();
  const LoopTotals& t = s.totals;
  std::printf("storetrack-host summary\n");
  std::printf("  observations in/used      %10" PRIu64 " / %" PRIu64 "\n", ac.observations_in,
              ac.observations_used);
  std::printf("  exposures complete/partial %9" PRIu64 " / %" PRIu64 " (dropped %" PRIu64
              ", numbering unknown %" PRIu64 ")\n",
              ac.exposures_complete, ac.exposures_partial_timeout + ac.exposures_partial_overflow,
              ac.exposures_dropped_too_few_cameras, ac.exposures_dropped_numbering_unknown);
  std::printf("  dropped: duplicate %" PRIu64 ", late %" PRIu64 ", time mismatch %" PRIu64
              ", unknown camera %" PRIu64 ", invalid %" PRIu64 "\n",
              ac.dropped_duplicate, ac.dropped_late, ac.dropped_time_mismatch,
              ac.dropped_unknown_camera, ac.dropped_invalid);
  std::printf("  dropped: spoofed %" PRIu64 ", quarantined %" PRIu64 ", time out of range %" PRIu64
              ", too few cameras %" PRIu64 "; sequence offset changes %" PRIu64
              ", restarts %" PRIu64 "\n",
              ac.dropped_spoofed, ac.dropped_quarantined, ac.dropped_time_out_of_range,
              ac.dropped_too_few_cameras, ac.sequence_offset_changes, ac.sequence_restarts);
  const auto& uc = s.udp.counters();
  if (s.cfg.udp_port > 0)
    std::printf("  udp: %" PRIu64 " datagrams, spoofed source %" PRIu64 ", kernel drops %" PRIu64
                ", receive budget exhausted %" PRIu64 "\n",
                uc.datagrams, uc.spoofed_source, uc.kernel_drops, uc.budget_exhausted);
  std::printf("  marks identified %" PRIu64 " of %" PRIu64 " (ambiguous %" PRIu64
              ", unmatched %" PRIu64 ")\n",
              ic.identified, ic.observations, ic.ambiguous_observation + ic.ambiguous_mark,
              ic.unmatched);
  std::printf("  samples valid/written      %9" PRIu64 " / %" PRIu64 " of %" PRIu64
              " exposures (withheld: no camera used %" PRIu64 ", fewer than min_cameras %" PRIu64
              ")\n",
              t.valid_samples, t.samples_written, t.exposures, t.withheld.no_camera_used,
              t.withheld.fewer_cameras_than_min);
  if (s.recording.ch10_open()) {
    const auto& cc = s.recording.ch10().counters();
    std::printf("  Chapter 10: %zu file(s), %" PRIu64 " samples written, %" PRIu64
                " dropped, %" PRIu64 " write / %" PRIu64 " sync errors\n",
                s.recording.ch10().files().size(), cc.messages_written,
                cc.messages_dropped + s.recording.counters().items_dropped_queue_full,
                cc.write_errors, cc.sync_errors);
  }
  const RecordingCounters rc = s.recording.counters();
  if (!s.recording.csv_path().empty() || s.recording.wants_marks_rows() ||
      !s.recording.rigid_csv_path().empty() || !s.recording.clearance_csv_path().empty())
    std::printf("  CSV write / close errors: fti %" PRIu64 " / %" PRIu64 ", marks %" PRIu64
                " / %" PRIu64 ", rigid %" PRIu64 " / %" PRIu64 ", clearance %" PRIu64 " / %" PRIu64
                "\n",
                rc.csv_write_errors, rc.csv_close_errors, rc.marks_csv_write_errors,
                rc.marks_csv_close_errors, rc.rigid_csv_write_errors, rc.rigid_csv_close_errors,
                rc.clearance_csv_write_errors, rc.clearance_csv_close_errors);
  std::printf("  iNET-X: %" PRIu64 " sent, %" PRIu64 " send errors\n",
              s.inetx.counters().packets_sent, s.inetx.counters().send_errors);
  std::printf(
      "  latency last obs -> iNET-X p50 %.0f us, p99 %.0f us, max %.0f us (%zu complete "
      "exposures)\n",
      static_cast<double>(t.latency_complete.percentile(0.5)) * 1e-3,
      static_cast<double>(t.latency_complete.percentile(0.99)) * 1e-3,
      static_cast<double>(t.latency_complete.max()) * 1e-3, t.latency_complete.count());
}

bool write_stats_json(const nlohmann::json& stats, const std::string& path) {
  std::ofstream out(path);
  out << stats.dump(2) << "\n";
  out.close();
  return static_cast<bool>(out);
}

nlohmann::json live_stats_json(const live::LiveServerCounters& c, std::uint64_t publications) {
  return {{"snapshots_published", publications},
          {"snapshots_read", c.snapshots_read},
          {"requests", c.requests},
          {"not_found", c.not_found},
          {"events_sent", c.events_sent},
          {"clients_peak", c.clients_peak},
          {"clients_refused", c.clients_refused},
          {"clients_dropped", c.clients_dropped}};
}

}  // namespace storetrack::hostapp
