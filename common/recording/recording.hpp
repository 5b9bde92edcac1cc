#pragma once
// Recording: one recorded training session in memory, as lancet-viz records it and as
// lancet-report, the metrics and the replay read it back (recording/hdf5_io.hpp reads and writes the
// HDF5 file; docs/RECORDING.md describes the file for h5py and MATLAB users).
//
// What a session is: from the tick at which lancet-rt applied the recording's reset (a fresh
// servo state, a fresh scene) to the end of the recording. It holds
//   - every servo tick (ToolSample: the servo's inputs — device reading, commands, liveness,
//     the patch version used — and its outputs — tool and proxy pose, force, stage, events —
//     and every kServoHashEvery ticks the hash of the servo's state), at 1 kHz;
//   - every visualizer frame (FrameRecord): which samples the scene had applied, the time the
//     blood was advanced, the patch it published, the task's figures after it, and every
//     kSceneHashEvery frames the hash of the scene;
//   - the scenario file's text and the arm's configuration text, the build's version and the
//     shared layout hash it was recorded with.
// Units: SI (m, N, s), times in ns of CLOCK_MONOTONIC (t_ns), blood in mL, volumes in mm³.

#include <cstdint>
#include <string>
#include <vector>

#include "lancet/shared_model/messages.hpp"
#include "lancet/shared_model/shared_state.hpp"

namespace lancet::record {

/// The file format's version (the /meta attribute format_version). 2: written in HDF5's SWMR mode
/// (a file whose writer died is readable up to its last flush), /meta/first_patches with
/// /meta/first_patch_versions, FrameRecord::ticks. Version 1 files (one /meta/first_patch; frames
/// delimited by last_seq) are still read.
inline constexpr std::uint32_t kFormatVersion = 2;

/// The scene hash (FrameRecord::scene_hash) is taken every this many frames.
inline constexpr std::uint32_t kSceneHashEvery = 30;

/// One visualizer frame of the session.
struct FrameRecord {
  std::uint64_t frame = 0;         ///< 0, 1, 2, ... from the start of the recording
  std::int64_t t_ns = 0;           ///< the viz clock (CLOCK_MONOTONIC) at the frame
  std::uint64_t last_seq = 0;      ///< newest ToolSample::seq the scene had applied after this frame (0: none yet)
  /// How many recorded ticks the scene applied this frame (format 2): the replay takes exactly these,
  /// whatever their seq says (a sample garbled in the segment may carry any seq).
  std::uint64_t ticks = 0;
  double blood_dt = 0;             ///< s of blood simulated this frame
  // The TissuePatch published this frame (patch_version 0: none).
  std::uint64_t patch_version = 0; ///< the seqlock version it was published as (ToolSample::patch_version refers to it)
  std::uint64_t patch_seq = 0;     ///< TissuePatch::seq
  std::int64_t patch_t_ns = 0;     ///< TissuePatch::t_ns
  std::uint64_t patch_samples_applied = 0;  ///< TissuePatch::samples_applied
  Vec3 patch_centre{};             ///< m, where it was cut out around
  // The left hand's patch published this frame, likewise (left_patch_version 0: none; the fields
  // above are the right hand's). Absent from files recorded before two hands: 0.
  std::uint64_t left_patch_version = 0;
  std::uint64_t left_patch_seq = 0;
  std::int64_t left_patch_t_ns = 0;
  std::uint64_t left_patch_samples_applied = 0;
  Vec3 left_patch_centre{};
  // The task and the tissue after this frame.
  double task_progress = 0;        ///< 0..1 (incision: line covered; drill: window bone removed)
  double max_deviation = 0;        ///< m, incision: farthest cut point from the line (x-y)
  double outside = 0;              ///< incision: fraction of the cut length off the line
  std::uint32_t damaged = 0;       ///< bit i: the scenario's avoid[i] has been reached
  double drilled_mm3 = 0;          ///< bone removed by the drill so far (mm³)
  double drilled_outside_mm3 = 0;  ///< of it, outside the drill task's window (mm³)
  double blood_lost_ml = 0;        ///< all blood sources so far (mL)
  double blood_on_tissue_ml = 0;   ///< on the tissue now (mL)
  double blood_swabbed_ml = 0;     ///< removed by the swab so far (mL)
  std::uint64_t scene_hash = 0;    ///< the scene's hash after this frame (0: not taken this frame)
};

/// What happened to the tissue in a frame, beyond the servo's own events (which its samples carry:
/// rupture, cut progress, grab, pull, release, drill removal).
struct SceneEvent {
  enum Kind : std::uint32_t {
    kBloodSource = 1,     ///< a blood source began (index: its number; value: mL/s; name: what it is)
    kBleedingStopped = 2, ///< a vessel stopped bleeding, pressed long enough (index: the source)
    kStructureReached = 3,///< a protected structure was reached (index: the scenario's avoid entry)
    kBoneDrilled = 4,     ///< bone removed by the drill this frame (value: mm³; position: the last removal)
  };
  std::uint64_t frame = 0;    ///< FrameRecord::frame it happened in
  std::int64_t t_ns = 0;      ///< that frame's time
  std::uint32_t kind = 0;     ///< Kind
  std::uint32_t index = 0;
  Vec3 position{};            ///< m
  double value = 0;
  char name[48] = {};         ///< NUL-terminated, truncated
};

/// A whole session.
struct Recording {
  // Provenance.
  std::uint32_t format_version = kFormatVersion;
  std::string lancet_version;      ///< the build that recorded it (git describe)
  std::uint64_t layout_hash = 0;   ///< kSharedLayoutHash of that build (informative)
  /// kRecordedLayoutHash of that build: replay refuses another. 0 in files written before the
  /// attribute existed (replay then goes by layout_hash; see Replay::create).
  std::uint64_t recorded_layout_hash = kRecordedLayoutHash;
  std::uint64_t protocol = 0;      ///< kProtocolVersion of that build
  std::string created;             ///< ISO 8601 UTC time the recording started
  std::string scenario_name;       ///< "" without a scenario
  std::string scenario_toml;       ///< the scenario file's whole text ("" without one)
  std::string scenario_file;       ///< the path it was loaded from (informative)
  std::string arm_config;          ///< the right hand's arm's hw_config text ("" for the built-in simulated stylus)
  std::string left_arm_config;     ///< the left hand's, likewise
  std::string tissue;              ///< without a scenario: lancet-viz's --tissue ("block" or "phantom")
  std::string volume_path;         ///< lancet-viz's --volume ("" when none)
  double patch_radius = 0.03;      ///< m, lancet-viz's --patch-radius-mm
  /// Hands recorded (1 or 2): the samples of hand h exist for h < hands.
  std::uint32_t hands = 1;
  /// Each hand's servo model as lancet-rt published it (ServoModelBlob: the replay steps with
  /// exactly it), by Hand; the left's only when hands is 2.
  ServoModelBlob servo_model[kHandCount]{};
  /// The patches the first recorded ticks may use before the first recorded frame publishes one:
  /// each hand's reset tick's and every newer one published before the recording began (by hand,
  /// TissuePatch::hand, then versions ascending, one patch each; a version is the hand's own).
  std::vector<std::uint64_t> first_patch_versions;
  std::vector<TissuePatch> first_patches;
  std::int64_t period_ns = 1'000'000;  ///< the servo period
  std::uint32_t servo_hash_every = 0;  ///< ToolSample::state_hash is set every this many ticks
  std::uint32_t scene_hash_every = 0;  ///< FrameRecord::scene_hash is set every this many frames
  // Data.
  std::vector<ToolSample> samples;  ///< every tick of every hand in tick order (right, then left), seq consecutive per hand (gaps: see samples_lost)
  std::vector<FrameRecord> frames;  ///< every frame, in order
  std::vector<SceneEvent> events;   ///< the tissue's events, in order
  // What the recorder saw go wrong (0 for a complete recording).
  std::uint64_t samples_lost = 0;   ///< ticks missing from `samples` (the sample ring overflowed)
  std::uint64_t gaps = 0;           ///< places where seq jumped
  /// The recorder never finished the file (the viz was killed, the machine lost power): what it
  /// had flushed is here (every row up to its last flush, a quarter second at most before the
  /// end), frames that applied ticks the file does not hold are dropped.
  bool cut_short = false;
};

}  // namespace lancet::record
