#include "replay.hpp"

#include "storetrack/ingest/receivers.hpp"
#include "storetrack/msg/canfd_codec.hpp"
#include "storetrack/msg/udp_codec.hpp"

namespace storetrack::post {

using ingest::RawSourceKind;

void Replay::feed(const ch10read::RawObservation& record) {
  ++counters_.records;
  const auto kind = static_cast<RawSourceKind>(record.source_kind);
  if (kind == RawSourceKind::kAlignerDeadline) {
    ++counters_.deadline_events;
    chain_.aligner->poll(record.host_mono_ns, ready_);
  } else if (kind == RawSourceKind::kAlignerFlush) {
    ++counters_.flush_events;
    chain_.aligner->flush(ready_);
  } else if (kind == RawSourceKind::kUdp || kind == RawSourceKind::kCanFd) {
    if (!(record.flags & msg::raw_observation_flags::kAccepted)) {
      ++counters_.refused_live;
      return;
    }
    msg::AnyMessage message;
    const msg::DecodeError e =
        kind == RawSourceKind::kUdp
            ? msg::decode_datagram(record.bytes, message)
            : msg::decode_canfd_stream(record.source_address, record.bytes, message);
    if (e != msg::DecodeError::kNone) {
      ++counters_.undecodable;
      return;
    }
    if (const auto* obs = std::get_if<msg::MarkObservations>(&message)) {
      ++counters_.observations;
      chain_.aligner->push(*obs, record.host_mono_ns, ready_);
    } else {
      ++counters_.health_messages;
    }
  } else {
    ++counters_.unknown_kind;
    return;
  }
  process_ready();
}

void Replay::finish() {
  counters_.pending_at_end = chain_.aligner->pending();
}

// As the host loop: every exposure in release order through the chain (hostapp::process_exposure:
// exclude's filter, the processor, the calibration health test); a sample too few cameras
// measured is withheld.
void Replay::process_ready() {
  for (const auto& exposure : ready_) {
    const hostapp::ProcessedExposure done = hostapp::process_exposure(chain_, exposure);
    const pipeline::AlignedExposure& e = *done.exposure;
    const pipeline::ExposureResult& r = done.result;
    ++counters_.exposures;
    const bool written = counters_.withheld.admit(
        hostapp::judge_sample(r.cameras_used, chain_.aligner->config().min_cameras));
    if (on_exposure_) on_exposure_(e, r, written, done.processor_rebuilt);
    if (!written) continue;
    samples_.push_back(r.sample);
    if (collect_) measurements_.push_back(smooth::measurement_from(r));
    if (on_sample_) on_sample_(r);
    if (clearance_csv_ && done.clearance_evaluated) {
      clearance_rows_.clear();
      hostapp::format_clearance_rows(r.sample, done.clearance_extrapolated, *chain_.clearance,
                                     clearance_rows_);
      clearance_csv_->write(clearance_rows_);
    }
  }
  ready_.clear();
}

}  // namespace storetrack::post
