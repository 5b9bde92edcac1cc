#pragma once
// RecorderControl: lancet-viz's recording, as a state machine around the live frame.
//
//   off ──arm()──▶ armed ──the servo uses a patch of this viz: its reset is sent──▶ waiting for
//   the reset ──the tick that applied it arrives──▶ on (every tick and frame written) ──stop()──▶ off
//
// Armed, the fresh scene the caller made for the recording takes no samples (what the servo sends
// before its reset belongs to no session); waiting, only the ticks from the reset on. With two
// hands, both hands' resets go out at once (VizSession::send_each_hand), so lancet-rt applies them
// in one tick. The patches this viz published while armed are kept (each hand's newest
// kArmedPatches), because the servo's first recorded ticks may use one published a frame or two
// before the recording begins. lancet-rt going
// away ends the recording (its servo state went with it); with --record FILE the next attempt is
// armed for FILE-2.h5, FILE-3.h5, ... Not real-time; prints what it does on stdout.

#include <array>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "app/viz_session.hpp"
#include "recording/hdf5_io.hpp"
#include "sim/scene_sim.hpp"
#include "sim/viz_frame.hpp"

namespace lancet::viz {

class RecorderControl {
 public:
  enum class State { kOff, kArmed, kWaitingReset, kOn };

  /// record_path: --record ("" none: off until arm()); the run's scene setup and the build's
  /// version go into every recording's metadata.
  RecorderControl(std::string record_path, sim::SceneSetup setup, std::string scenario_name, std::string lancet_version);
  ~RecorderControl();
  RecorderControl(const RecorderControl&) = delete;
  RecorderControl& operator=(const RecorderControl&) = delete;

  /// Arms a recording to `path`; the caller has just made the fresh scene it will record.
  void arm(std::string path);
  /// Called with the file's path each time a recording is finished whole (none: nothing called).
  void set_on_recorded(std::function<void(const std::string&)> on_recorded) { on_recorded_ = std::move(on_recorded); }
  /// Says why a recording could not be armed (shown on the panel).
  void set_message(std::string message) { message_ = std::move(message); }
  /// Finishes the file being written (if any) and turns recording off.
  void stop();

  /// The frame's drained samples → the part the scene takes: none while armed, those from the
  /// servo's reset on while waiting for it (the recording starts there), all of them otherwise.
  /// Recording, they are written too.
  [[nodiscard]] std::span<const ToolSample> admit(std::span<const ToolSample> batch, VizSession& session);
  /// After the frame (the scene stepped, the patch published or not, at now_ns): keeps the armed
  /// patches, sends the servo's reset once it uses one of them, writes the frame when recording.
  void after_frame(VizSession& session, sim::SceneSim& sim, const sim::FrameResult& frame, std::int64_t now_ns);
  /// After lancet-rt went away (session.rt_losses() grew): ends the recording. Returns the path of
  /// the next attempt to arm on a fresh scene (--record FILE: FILE-2.h5 ...; "" none).
  [[nodiscard]] std::string after_rt_loss(const VizSession& session);

  [[nodiscard]] State state() const noexcept { return state_; }
  /// The panel's line: what is being recorded, what it waits for, or the last outcome.
  [[nodiscard]] std::string panel_line() const;

 private:
  void begin(std::span<const ToolSample> from_reset, VizSession& session);
  void keep_published(const VizSession& session, const std::array<bool, kHandCount>& published);
  /// Whether every hand in use has a sample using a patch this viz kept while armed.
  [[nodiscard]] bool servo_uses_ours(const VizSession& session) const;

  static constexpr std::size_t kArmedPatches = 8;
  std::string record_path_;  ///< --record ("" none)
  sim::SceneSetup setup_;
  std::string scenario_name_, lancet_version_;
  State state_ = State::kOff;
  std::string path_;         ///< of the recording armed or being written
  int parts_ = 1;            ///< --record FILE: attempts recorded so far
  std::uint32_t rt_losses_seen_ = 0;
  std::unique_ptr<record::Recorder> recorder_;
  std::uint64_t frames_ = 0, last_seq_ = 0, frame_ticks_ = 0;
  std::vector<record::SceneEvent> events_;
  std::string message_;
  std::function<void(const std::string&)> on_recorded_;
  /// By hand: (version, patch), newest last.
  std::array<std::deque<std::pair<std::uint64_t, std::unique_ptr<TissuePatch>>>, kHandCount> armed_patches_;
};

}  // namespace lancet::viz
