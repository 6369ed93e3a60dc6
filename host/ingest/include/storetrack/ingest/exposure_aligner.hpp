// ExposureAligner: groups the MarkObservations of one exposure across cameras, releasing each
// exposure when every rig camera has delivered it or when its bounded wait expires, so one dead
// camera never stalls the output. Pure logic: the caller supplies the host's monotonic time, so
// tests inject faults deterministically (tests/host/ingest). Design (docs/architecture.md,
// "Exposure alignment"):
//  - Exposures are keyed on the aligner's own exposure index. Each camera maps its trigger
//    sequence onto it with its own offset (0 while the rig shares one trigger), so one camera's
//    sequence can never move the others': a sequence that does not fit (further ahead than the
//    others can reach within the wait, far behind, or naming an exposure whose mid-time
//    disagrees) is QUARANTINED, and the camera's
//    offset is re-learned from the exposure mid-time (the trigger grid) only when two of its
//    observations in a row agree on the new offset. A restart of the whole trigger is accepted
//    when a majority of cameras agree on it. When the unit's TAI stepped against its own
//    monotonic clock, its time is what is wrong: the sequence is kept and the time judged.
//  - A sequence further ahead than the lead window is a GAP, not a fault, when its time lies on
//    the trigger grid at that index and it does not come from the future (its host arrival
//    minus its mid-time is no less than the smallest such lag seen, less the wait): every unit's
//    datagrams lost together (a full socket buffer) make such jumps. A forged or glitched
//    sequence ahead is from the future or off the grid, and stays quarantined. A trigger restart
//    needs a time discontinuity: held observations of a majority that lie on the grid at their
//    own sequence are a gap too.
//  - An exposure times out when the host waited max_wait for it AND observations went on being
//    placed for max_wait since (host time between placements, silences longer than half the
//    wait left out) or nothing was placed for max_wait: a host
//    that was descheduled and now reads the socket's backlog (its clock jumped, the datagrams
//    did not) does not release exposures whose cameras are still in the backlog.
//  - A released exposure is numbered in the rig's trigger numbering: the one most cameras share
//    (their offset onto the exposure index), not a vote among that exposure's own cameras. A
//    unit renumbered from 0 is one camera of the rig even when an exposure holds it and one other
//    camera only, and even when a restarted host heard it first and indexed exposures by it.
//    Once chosen, a tie keeps it; while no numbering has more cameras than every other (a host
//    that so far heard one camera of each), an exposure is dropped and counted, not guessed.
//  - An exposure's reference mid-time is the majority of its cameras (the mid-time most of them
//    agree with, ties broken by the trigger grid), never the first to arrive; the others are
//    dropped as time mismatches.
//  - A camera exposes each (trigger sequence, start time) once: a repeat of one it delivered
//    recently is a duplicate whatever its duration (and so its mid-time) says, even when a
//    re-learned offset maps it onto another exposure index.
//  - Only configured (camera id, unit id) pairs are accepted; times that could overflow int64
//    arithmetic are refused. Every observation is either used or counted by its reason, and
//    every container is bounded (max_pending exposures x rig cameras, one held observation per
//    camera, a fixed history, the last 1024 delivered (sequence, start) ids per camera).
#pragma once

#include <array>
#include <cstdint>
#include <deque>
#include <map>
#include <optional>
#include <set>
#include <utility>
#include <vector>

#include "storetrack/msg/messages.hpp"
#include "storetrack/pipeline/aligned_exposure.hpp"
#include "storetrack/time/time.hpp"

namespace storetrack::ingest {

/// Limits checked by the ExposureAligner constructor (and by the host configuration reader).
inline constexpr std::size_t kMaxAlignerCameras = 32;  ///< one bit per camera in the masks
inline constexpr time::MonotonicNs kMaxAlignerWaitNs = 60 * time::kNsPerSecond;
inline constexpr std::int64_t kMaxMidTimeSpreadNs = time::kNsPerSecond;
inline constexpr std::size_t kMaxAlignerPending = 4096;
inline constexpr std::uint32_t kMaxSequenceLead = 100'000;
/// The fastest trigger the aligner assumes before it has measured the period (1000 fps): until
/// then the lead window is counted in exposures of this period.
inline constexpr time::MonotonicNs kFastestTriggerPeriodNs = 1'000'000;
/// The lead window in trigger time, whatever the wait: a camera may open an exposure at most
/// min(max_wait, this) / period ahead of the newest one without judging the jump. A longer wait
/// (tools/testpoint's 5 s) must not let one forged datagram thousands of exposures ahead count as
/// a camera legitimately ahead. 10 ms: the production wait, the units' latency differences.
inline constexpr time::MonotonicNs kMaxLeadTimeNs = 10'000'000;
/// Exposure start times outside [0, kMaxExposureStartTaiNs] are refused: 2^62 ns is year 2116,
/// and within this range every sum and difference of two times fits int64.
inline constexpr time::TaiNs kMaxExposureStartTaiNs = std::int64_t{1} << 62;

struct AlignerConfig {
  /// Camera ids in rig order (rig.cameras[i].id): bit i of missing_camera_mask is camera_ids[i].
  std::vector<int> camera_ids;
  /// Unit id of each camera, same order (rig.cameras[i].unit_id). An observation naming a camera
  /// with another unit id is counted as spoofed. Empty: not checked.
  std::vector<int> unit_ids;
  /// Longest wait for the missing cameras of an exposure, from its first observation's arrival
  /// (host CLOCK_MONOTONIC). Bounds the latency added by a dead camera. (0, 60 s].
  time::MonotonicNs max_wait_ns = 10'000'000;
  /// Cameras of one exposure whose mid-points (TAI) differ from the majority's by more than this
  /// are inconsistent (a unit's clock jumped): they are dropped. [0, 1 s].
  std::int64_t max_mid_time_spread_ns = 2'000'000;
  /// Exposures waiting at once; beyond it the oldest is released early (counted). 1..4096.
  std::size_t max_pending = 64;
  /// Exposures with fewer delivered cameras are dropped (counted), not released. 1..cameras.
  int min_cameras = 1;
  /// A camera may open a new exposure at most this far ahead of the newest one without its jump
  /// being judged (its own continuity, the grid and its arrival time); the window is also at
  /// most min(max_wait, kMaxLeadTimeNs) / period, so it does not grow with the wait. 1..100000.
  std::uint32_t max_sequence_lead = kMaxSequenceLead;
};

/// Why observations or exposures were dropped, and what was released. All counts since start.
/// After flush(): observations_in = observations_used + every dropped_* counter.
struct AlignerCounters {
  std::uint64_t observations_in = 0;
  std::uint64_t observations_used = 0;
  std::uint64_t exposures_complete = 0;          ///< released with every camera
  std::uint64_t exposures_partial_timeout = 0;   ///< released on the deadline, cameras missing
  std::uint64_t exposures_partial_overflow = 0;  ///< released early: too many pending
  std::uint64_t exposures_dropped_too_few_cameras = 0;
  /// Released while no camera had placed an observation with its current offset (every camera
  /// heard so far re-learning its numbering): no numbering to write. A tie between numberings is
  /// not this: it goes to the one that counted the most trigger edges.
  std::uint64_t exposures_dropped_numbering_unknown = 0;
  std::uint64_t dropped_unknown_camera = 0;     ///< camera_id not in the rig
  std::uint64_t dropped_spoofed = 0;            ///< unit_id is not the camera's calibrated unit
  std::uint64_t dropped_invalid = 0;            ///< invalid sequence or mark count
  std::uint64_t dropped_time_out_of_range = 0;  ///< start time outside [0, 2^62] ns
  std::uint64_t dropped_duplicate = 0;          ///< same camera, same exposure, seen before
  std::uint64_t dropped_late = 0;               ///< exposure already released without it
  std::uint64_t dropped_time_mismatch = 0;      ///< mid-time disagrees with the majority
  /// Sequence did not fit and was not confirmed, or opened an exposure alone past a jump that no
  /// other camera confirmed before its wait ended (taken back, never released).
  std::uint64_t dropped_quarantined = 0;
  std::uint64_t dropped_too_few_cameras = 0;  ///< observations of exposures below min_cameras
  std::uint64_t dropped_numbering_unknown =
      0;  ///< observations of exposures_dropped_numbering_unknown
  std::uint64_t sequence_offset_changes = 0;  ///< a camera's offset re-learned from time
  std::uint64_t sequence_restarts = 0;        ///< a majority of cameras restarted together
  std::uint64_t camera_missing_total = 0;     ///< sum over released exposures of missing cameras
};

struct CameraCounters {
  std::uint64_t received = 0;
  std::uint64_t used = 0;
  std::uint64_t missing = 0;  ///< released exposures without this camera
  std::uint64_t time_mismatch = 0;
  std::uint64_t late = 0;
  std::uint64_t duplicate = 0;
  std::uint64_t spoofed = 0;
  std::uint64_t quarantined = 0;
  std::uint64_t offset_changes = 0;
  /// Current offset: exposure index = unwrapped trigger_seq + offset.
  std::int64_t sequence_offset = 0;
};

class ExposureAligner {
 public:
  /// Throws std::invalid_argument naming the field and its range when the config is outside the
  /// limits above.
  explicit ExposureAligner(AlignerConfig config);

  /// Adds one observation received at host time `now`; appends released exposures to `out`.
  void push(const msg::MarkObservations& obs, time::MonotonicNs now,
            std::vector<pipeline::AlignedExposure>& out);
  /// Releases exposures whose wait expired by `now`. Returns true when it changed anything
  /// (released or took back an exposure): a call that returns false left the aligner as it was,
  /// so a replay that repeats only the calls that returned true, at their `now`, is exact.
  bool poll(time::MonotonicNs now, std::vector<pipeline::AlignedExposure>& out);
  /// Releases everything pending and drops held observations (end of input).
  void flush(std::vector<pipeline::AlignedExposure>& out);
  /// Host time at which the next pending exposure times out and something is released or taken
  /// back; INT64_MAX when none pending.
  time::MonotonicNs next_deadline() const;

  std::size_t pending() const { return pending_.size(); }
  /// Observations held in quarantine (at most one per camera).
  std::size_t held() const;
  const AlignerCounters& counters() const { return counters_; }
  const std::vector<CameraCounters>& camera_counters() const { return camera_counters_; }
  const AlignerConfig& config() const { return config_; }

 private:
  enum class Opening : std::uint8_t {
    kJudged,         // within the lead window, or a jump its camera's stream or a majority vouches
    kFirstOfRun,     // the first exposure: nothing to judge it by
    kByArrivalTime,  // a jump on the grid, not from the future: other cameras must confirm it
  };
  struct Pending {
    std::vector<msg::MarkObservations> cameras;  // at most one per rig camera
    std::uint32_t present_mask = 0;
    time::MonotonicNs first_arrival = 0;
    time::MonotonicNs last_arrival = 0;
    time::TaiNs reference_mid_tai_ns = 0;  // majority mid-time of the cameras so far
    // How its first observation was judged. While it holds that camera alone, an
    // exposure not kJudged is taken back (quarantined) when a camera places an observation more
    // than the lead window behind it; one kByArrivalTime also when its wait ends or at flush.
    Opening opening = Opening::kJudged;
    std::int64_t stream_ns_at_open = 0;  // the stream clock when its first camera was placed
  };
  using DeliveredId = std::pair<std::uint32_t, time::TaiNs>;  // trigger_seq, exposure start
  struct CameraState {
    bool seen = false;
    std::int64_t last_unwrapped = 0;  // unwrapped trigger_seq of the last placed observation
    std::int64_t offset = 0;          // exposure index = unwrapped trigger_seq + offset
    // Observations placed with the current `offset` and not taken back: only such a camera has a
    // say in the rig's numbering (one whose lone exposure was taken back placed nothing).
    std::uint32_t placements_with_offset = 0;
    bool holding = false;  // an observation in quarantine
    msg::MarkObservations held{};
    std::optional<std::int64_t> held_offset;  // the offset its mid-time implies, if any
    // TAI - unit monotonic time when this camera last agreed with the majority: a change means
    // the unit's TAI stepped (a clock fault), not its sequence.
    bool have_clock_baseline = false;
    std::int64_t tai_minus_mono_ns = 0;
    // The newest exposure index this camera placed an observation in, and when (host time): a
    // camera's own stream vouches for a jump ahead of it only as far as the trigger can have run
    // since (one exposure per period) plus the lead window.
    bool placed_any = false;
    std::int64_t frontier_key = 0;
    time::MonotonicNs frontier_arrival = 0;
    // (trigger_seq, start) of its last kRecentDelivered placed observations, oldest first.
    std::set<DeliveredId> delivered;
    std::deque<DeliveredId> delivered_order;
  };
  struct Released {
    std::int64_t key = INT64_MIN;
    std::uint32_t mask = 0;
    time::TaiNs mid = 0;
  };
  struct Majority {
    std::uint32_t inlier_mask = 0;  // bit = index in Pending::cameras
    std::size_t reference = 0;      // index of the camera whose mid-time the majority shares
  };
  enum class ReleaseReason { kComplete, kTimeout, kOverflow, kFlush };
  using PendingMap = std::map<std::int64_t, Pending>;  // by exposure index

  int camera_index(int camera_id) const;
  bool accept_fields(const msg::MarkObservations& obs, int cam);
  std::int64_t unwrap(const CameraState& cs, std::uint32_t seq) const;
  void place(int cam, const msg::MarkObservations& obs, time::MonotonicNs now,
             bool gap_confirmed = false);
  bool gap_explained(std::int64_t key, time::TaiNs mid, time::MonotonicNs now) const;
  bool continues_own_stream(int cam, std::int64_t key, time::MonotonicNs now) const;
  bool lone_unjudged(const Pending& p) const;
  bool forces_older(const Pending& p) const;
  void take_back(PendingMap::iterator it);
  bool take_back_expired_unconfirmed(time::MonotonicNs now);
  bool on_grid_over_gap(std::int64_t key, time::TaiNs mid) const;
  bool held_on_grid(int cam) const;
  void advance_stream_clock(time::MonotonicNs now);
  time::MonotonicNs deadline_of(const Pending& p) const;
  void update_lag_baseline(const Pending& p, time::TaiNs reference_mid, int agreeing_cameras);
  bool on_grid(std::int64_t key, time::TaiNs mid) const;
  bool in_time_order(std::int64_t key, time::TaiNs mid) const;
  std::int64_t lead_limit() const;
  std::int64_t match_tolerance() const;
  bool clock_stepped(const CameraState& cs, const msg::MarkObservations& obs) const;
  struct NumberingVote {
    std::optional<std::int64_t> leader;  // the offset most cameras map their sequence with
    std::size_t votes = 0;
    bool tied = false;  // another offset has as many cameras
  };
  std::size_t numbering_votes(std::int64_t offset) const;
  NumberingVote numbering_vote() const;
  void note_rig_numbering();
  std::optional<std::uint32_t> rig_sequence(std::int64_t key);
  void add_to_pending(PendingMap::iterator it, int cam, const msg::MarkObservations& obs,
                      time::MonotonicNs now);
  void drop_known(std::int64_t key, int cam);
  void evict_lone_exposures_ahead_of(std::int64_t key);
  void recompute_newest_key(std::int64_t floor_key);
  void quarantine(int cam, const msg::MarkObservations& obs, std::int64_t unwrapped,
                  time::MonotonicNs now);
  void try_trigger_restart(time::MonotonicNs now);
  void drop_held(int cam);
  bool delivered_before(int cam, const msg::MarkObservations& obs) const;
  void remember_delivered(int cam, const msg::MarkObservations& obs);
  std::optional<std::int64_t> exposure_at_time(time::TaiNs mid) const;
  std::optional<time::TaiNs> grid_mid(std::int64_t key) const;
  Majority majority(const std::vector<msg::MarkObservations>& cameras, std::int64_t key) const;
  void release(PendingMap::iterator it, ReleaseReason reason,
               std::vector<pipeline::AlignedExposure>& out);
  bool release_ready(time::MonotonicNs now, std::vector<pipeline::AlignedExposure>& out);
  void remember_released(std::int64_t key, std::uint32_t mask, time::TaiNs mid);
  void update_grid(std::int64_t key, time::TaiNs mid, int agreeing_cameras);
  const Released* released_entry(std::int64_t key) const;

  AlignerConfig config_;
  std::uint32_t all_mask_ = 0;
  std::size_t restart_quorum_ = 1;  // cameras that must agree on a trigger restart
  bool restarting_ = false;
  // The offset of the rig's numbering, chosen when one leads with two cameras or more (at each
  // camera's first placement with a new offset, and at each release), or at a release before
  // any choice on a tie (the numbering that counted the most edges); kept until another leads
  // with two cameras or more, so the numbering of the samples does not flip between exposures
  // and goes on when every camera that carried it has renumbered.
  std::optional<std::int64_t> rig_offset_;
  PendingMap pending_;
  bool have_key_ = false;
  std::int64_t newest_key_ = 0;        // newest exposure index opened
  std::int64_t released_through_ = 0;  // every exposure <= this has been released
  bool released_any_ = false;
  time::TaiNs newest_released_mid_ = INT64_MIN;  // latest mid-time released: restarts come after
  // The trigger grid, from released exposures: last index and mid-time, and the period.
  std::int64_t grid_key_ = 0;
  time::TaiNs grid_mid_ = 0;
  std::int64_t grid_period_ns_ = 0;  // 0: not known yet
  int grid_misses_ = 0;              // consecutive lone exposures off the grid
  // Host time of the last observation placed: an exposure waits past its own deadline while
  // observations keep coming but the stream has not moved on (a stalled host's backlog).
  time::MonotonicNs last_placed_ = INT64_MIN;
  std::int64_t stream_ns_ = 0;  // host time while placing, silences left out (monotone)
  // Smallest (host arrival - mid-time) of released majority exposures, over the current and the
  // previous window of kHistory releases (so a drift of the host clock against TAI is followed):
  // a datagram arriving earlier than that, by more than the wait, is from the future.
  time::MonotonicNs lag_min_current_ = INT64_MAX;
  time::MonotonicNs lag_min_previous_ = INT64_MAX;
  std::size_t lag_window_releases_ = 0;
  static constexpr std::size_t kHistory = 1024;
  static constexpr std::int64_t kRecentReleased = 8;         // searched when re-learning an offset
  static constexpr std::size_t kRecentDelivered = kHistory;  // per camera, for duplicates
  std::array<Released, kHistory> history_{};
  std::vector<CameraState> cameras_;
  AlignerCounters counters_;
  std::vector<CameraCounters> camera_counters_;
};

}  // namespace storetrack::ingest
