#include "app/viz_app.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <exception>
#include <thread>

#include "app/viz_summary.hpp"
#include "render/image.hpp"
#include "volume/tf_editor.hpp"

namespace lancet::viz {

/// The GL side of the app: made once the window's context is current, gone before it is.
struct VizApp::Screen {
  Screen(const VizOptions& o, render::Window& win, Interaction& ui)
      : renderer(o.width, o.height), overlay(win.handle(), !o.headless) {
    if (!o.headless) poller = std::make_unique<InputPoller>(win.handle(), ui);  // after the overlay: ours is the scroll
  }
  render::SceneRenderer renderer;
  render::Overlay overlay;
  std::unique_ptr<InputPoller> poller;  ///< null headless
  surface::TriangleMesh mesh;           ///< the scene's, as drawn
  surface::TriangleMesh with_pools;     ///< the drawn mesh and the grooves' blood pools
  std::vector<float> blood_depth, blood_age;
};

namespace {

VizSessionParams session_params(const VizOptions& o) {
  VizSessionParams p;
  p.shm_name = o.shm;
  return p;
}

}  // namespace

VizApp::VizApp(const VizOptions& o, render::Window& win, VizSources sources, std::string lancet_version)
    : o_(o),
      win_(win),
      sim_(std::move(sources.sim)),
      replay_(std::move(sources.replay)),
      trace_(std::move(sources.trace)),
      tool_(std::move(sources.tool)),
      station_(sources.station),
      session_(session_params(o)),
      recorder_(o.record_path, sim().setup(), sim().scenario() != nullptr ? sim().scenario()->name : "", std::move(lancet_version)),
      live_(session_, recorder_, trace_.get()),
      clock_(o.replay_speed) {
  if (station_ != nullptr) recorder_.set_on_recorded([this](const std::string& path) { station_->attempt_recorded(path); });
  const scenario::Scenario* scenario = sim().scenario();
  const std::vector<ToolMode> all{ToolMode::kProbe, ToolMode::kScalpel, ToolMode::kRetractor, ToolMode::kDrill, ToolMode::kSwab};
  offered_ = {scenario != nullptr ? scenario->tools : all, scenario != nullptr ? scenario->left_tools : all};
  for (std::size_t h = 0; h < kHandCount; ++h) keys_[h] = tool_keys(offered_[h]);
  if (!tool_.empty()) left_tool_ = scenario != nullptr ? tool_name(scenario->left_start_tool) : tool_;
  if (scenario != nullptr && scenario->task == scenario::TaskKind::kIncision) guide_ = sim().scene().drape(scenario->incision.line);
  for (auto p : volume::kTfPresets) preset_names_.emplace_back(volume::tf_preset_name(p));
  ui_.view = o.view;
  ui_.show_patch = o.show_patch;
  ui_.preset = o.preset;
  if (std::isfinite(o.clip_mm)) ui_.clip = true, ui_.clip_mm = o.clip_mm;
  if (scenario != nullptr) {
    ui_.yaw = static_cast<float>(scenario->camera.yaw);
    ui_.pitch = static_cast<float>(scenario->camera.pitch);
    ui_.distance = static_cast<float>(scenario->camera.distance);
  }
}

VizApp::~VizApp() = default;

int VizApp::run(const std::atomic<bool>& stop) {
  try {
    screen_ = std::make_unique<Screen>(o_, win_, ui_);
    sim().scene().draw_mesh(screen_->mesh);
    screen_->renderer.set_mesh(screen_->mesh);
    shown_revision_ = sim().scene().revision();
    const auto start = std::chrono::steady_clock::now();
    const auto frame_period = std::chrono::duration<double>(1.0 / o_.fps);
    last_frame_ = start;
    while (!stop.load(std::memory_order_relaxed) && !stop_ && !win_.should_close()) {
      const auto frame_start = std::chrono::steady_clock::now();
      if (time_up(std::chrono::duration<double>(frame_start - start).count())) break;
      const std::int64_t now = monotonic_ns();
      const double wall_dt = std::chrono::duration<double>(frame_start - last_frame_).count();
      last_frame_ = frame_start;
      if (replay_) {
        step_replay(wall_dt);
      } else {
        step_live(now, wall_dt);
      }
      upload_mesh_and_blood();
      if (!replay_ && session_.link_message() != last_message_) {
        last_message_ = session_.link_message();
        std::printf("lancet-viz: %s\n", last_message_.c_str());
        std::fflush(stdout);
      }
      if (!take_input(now)) break;
      draw(now);
      manage_recording();
      if (want_snapshot_) write_snapshot();
      if (!o_.headless) screen_->renderer.present(fw_, fh_);
      win_.swap_and_poll();
      ++frames_;
      std::this_thread::sleep_until(frame_start + frame_period);
    }
    if (!o_.screenshot.empty()) {
      const render::Image img = screen_->renderer.read_back();
      variance_ = render::luminance_variance(img);
      if (!render::write_png(o_.screenshot, img)) {
        std::fprintf(stderr, "lancet-viz: cannot write screenshot %s\n", o_.screenshot.c_str());
        exit_code_ = 1;
      } else {
        std::printf("lancet-viz: wrote %s (%dx%d, luminance variance %.1f)\n", o_.screenshot.c_str(), img.width, img.height,
                    variance_);
      }
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "lancet-viz: %s\n", e.what());
    exit_code_ = 4;
  }
  screen_.reset();
  return exit_code_;
}

bool VizApp::time_up(double elapsed_s) {
  if (o_.duration <= 0 || elapsed_s < o_.duration) return false;
  // Time is up; with --screenshot-view, one frame more in that view for the screenshot.
  if (o_.screenshot_view < 0 || screenshot_frame_) return true;
  ui_.view = o_.screenshot_view;
  screenshot_frame_ = true;
  return false;
}

void VizApp::step_live(std::int64_t now, double wall_dt) {
  // The blood simulates the time since the last frame (Bleeding::advance bounds a stall's).
  live_.begin(now, sim().bleeding() != nullptr ? wall_dt : 0.0);
  auto frame = sim::run_frame(sim(), live_);  // live, drain() cannot fail
  if (!frame.ok()) return;
  blood_ms_ += frame.value().blood_s * 1e3;
  recorder_.after_frame(session_, sim(), frame.value(), now);
  // The session's start: the tool (after the servo's reset, when recording is armed).
  if (!tool_.empty() && session_.link() == Link::kConnected && tool_sent_for_ != session_.connections()) {
    Command c{};
    c.kind = CommandKind::kSetToolMode;
    (void)tool_from_name(tool_, c.mode);  // CLI11 or the scenario admitted only the tools' names
    if (session_.send(c, now)) tool_sent_for_ = session_.connections();
  }
  // The left hand's, once lancet-rt says it drives two.
  if (!left_tool_.empty() && session_.link() == Link::kConnected && session_.hands() > 1 &&
      left_tool_sent_for_ != session_.connections()) {
    Command c{};
    c.kind = CommandKind::kSetToolMode;
    c.hand = Hand::kLeft;
    (void)tool_from_name(left_tool_, c.mode);
    if (session_.send(c, now)) left_tool_sent_for_ = session_.connections();
  }
}

void VizApp::step_replay(double wall_dt) {
  if (auto r = clock_.advance(*replay_, wall_dt, o_.headless); !r.ok()) {
    std::fprintf(stderr, "lancet-viz: --replay: %s\n", r.error().message.c_str());
    replay_error_ = r.error().message;
    exit_code_ = 1;
    stop_ = true;
  }
  if (o_.headless && replay_->done()) {  // then one frame drawn (in --screenshot-view, if given) and stop
    if (o_.screenshot_view < 0 || screenshot_frame_) {
      stop_ = true;
    } else {
      ui_.view = o_.screenshot_view;
      screenshot_frame_ = true;
    }
  }
}

void VizApp::upload_mesh_and_blood() {
  Screen& sc = *screen_;
  // Redraw only what changed shape; with the volume beneath, the grooves' walls are the
  // volume's to show.
  bool mesh_changed = false;
  if (sim().scene().revision() != shown_revision_ || (ui_.view == 1) != shown_walls_off_) {
    shown_revision_ = sim().scene().revision();
    shown_walls_off_ = ui_.view == 1;
    sim().scene().draw_mesh(sc.mesh, !shown_walls_off_);
    mesh_changed = true;
  }
  // The blood onto the mesh, with the pools in the grooves (they change every frame: the mesh
  // with them is sent every frame, only the blocks that differ).
  blood::Bleeding* blood = sim().bleeding();
  using Clock = std::chrono::steady_clock;
  const auto ms_since = [](Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); };
  if (blood != nullptr) {
    const auto t0 = Clock::now();
    blood->vertex_blood(sc.mesh, sc.blood_depth, sc.blood_age);
    if (blood->groove_cells() > 0) {
      sc.with_pools = sc.mesh;
      blood->append_pools(sim().scene(), sc.with_pools, sc.blood_depth, sc.blood_age);
      sc.renderer.set_mesh(sc.with_pools);
      mesh_changed = false;
    }
    blood_ms_ += ms_since(t0);
  }
  if (mesh_changed) sc.renderer.set_mesh(sc.mesh);
  if (blood != nullptr) {
    const auto t0 = Clock::now();
    sc.renderer.set_blood(sc.blood_depth, sc.blood_age);
    blood_ms_ += ms_since(t0);
  }
}

bool VizApp::take_input(std::int64_t now) {
  fw_ = o_.width, fh_ = o_.height;
  if (o_.headless) return true;
  Screen& sc = *screen_;
  win_.framebuffer_size(fw_, fh_);
  if (fw_ > 0 && fh_ > 0) sc.renderer.resize(fw_, fh_);
  const InputActions a =
      sc.poller->poll(ui_, offered_[hand_index(ui_.hand)], static_cast<int>(preset_names_.size()), sc.overlay.wants_mouse());
  if (a.quit) return false;
  if (a.stylus_released) session_.set_stylus_target(a.released_hand, false, {}, now);
  for (const Command& c : a.commands) (void)session_.send(c, now);
  if (a.snapshot) want_snapshot_ = true;
  if (a.record && !replay_) want_record_ = true;
  if (a.replay_pause && replay_) clock_.toggle_pause();
  int ww = 0, wh = 0;
  sc.poller->window_size(ww, wh);
  Vec3 p;
  if (ui_.mouse_drives_stylus && sc.renderer.pick_plane(ui_.last_x, ui_.last_y, ww, wh, p)) {
    // Pushed depth_mm below the surface under the cursor (or below z = 0 off the tissue).
    const auto top = sim().scene().surface_below(p.x, p.y);
    p.z = (top ? top->z : 0.0) - ui_.depth_mm * 1e-3;
    session_.set_stylus_target(ui_.hand, true, p, now);
  }
  return true;
}

void VizApp::draw(std::int64_t now) {
  Screen& sc = *screen_;
  const scenario::Scenario* scenario = sim().scenario();
  render::SceneInput in;
  // The tool and the patch: lancet-rt's, or the replay's.
  // The panel shows the hand the keys drive.
  const ToolSample* latest = replay_ ? replay_->latest(ui_.hand) : session_.has_sample(ui_.hand) ? &session_.latest(ui_.hand) : nullptr;
  for (std::size_t h = 0; h < kHandCount; ++h) {
    const auto hand = static_cast<Hand>(h);
    const ToolSample* t = replay_ ? replay_->latest(hand) : session_.has_sample(hand) ? &session_.latest(hand) : nullptr;
    render::ToolView& tv = in.tools[h];
    tv.has_tool = t != nullptr;
    if (t == nullptr) continue;
    tv.tool = t->tool.position;
    tv.proxy = t->proxy.position;
    tv.force = t->force;
    if (ui_.show_patch) {
      const TissuePatch* p = replay_ ? replay_->patch(hand) : session_.patch_version(hand) > 0 ? &session_.patch(hand) : nullptr;
      in.patches[h] = p;
    }
  }
  in.camera_yaw = ui_.yaw, in.camera_pitch = ui_.pitch, in.camera_distance = ui_.distance;
  if (scenario != nullptr) in.camera_target = scenario->camera.target;
  in.guide = guide_.empty() ? nullptr : &guide_;
  volume_.prepare(ui_, sim().scene(), sim().scene().take_volume_changes(), in);
  sc.renderer.render(in);

  auto lines = status_lines(session_, ui_, o_.headless, sim().scene().events(), scenario,
                            sim().task() != nullptr ? &sim().task()->status() : nullptr, keys_[hand_index(ui_.hand)]);
  if (replay_) replace_link_lines(lines, session_, *replay_, o_.replay_path, clock_.speed(), clock_.paused());
  if (ui_.view != 0) lines.push_back({volume_line(ui_, preset_names_, o_.headless)});
  render::PanelState panel = panel_state(now, latest);
  // ImGui sizes a panel from the frame before: the screenshot's extra frame (a line more) is
  // laid out once before it is drawn.
  if (screenshot_frame_) sc.overlay.layout("Lancet", lines, sc.renderer.width(), sc.renderer.height(), &panel);
  do_panel_actions(sc.overlay.draw("Lancet", lines, sc.renderer.width(), sc.renderer.height(), &panel), now);
}

render::PanelState VizApp::panel_state(std::int64_t now, const ToolSample* latest) {
  // The controls panel: task, tools, the force and the servo over the last seconds, the volume.
  const auto& rs = session_.rt_status();
  history_.add(latest != nullptr ? static_cast<float>(norm(latest->force)) : 0.0f,
               rs ? static_cast<float>(rs->wake_p99_ns) * 1e-3f : 0.0f);
  wake_.update(rs, now);
  render::PanelState panel;
  if (station_ != nullptr) {
    for (auto& [text, alert] : station_->panel_lines()) panel.trainee.push_back({std::move(text), alert});
  }
  if (sim().task() != nullptr) {
    panel.task_progress = static_cast<float>(sim().task()->status().progress);
    panel.task_label = sim().scenario()->task == scenario::TaskKind::kIncision ? "incision along the line" : "drill the window";
  }
  for (auto m : offered_[hand_index(ui_.hand)]) {
    panel.tools.emplace_back(tool_name(m));
    panel.tool_keys.push_back(static_cast<int>(m));
  }
  panel.tool = latest != nullptr ? static_cast<int>(latest->mode) : -1;
  panel.force_history = history_.force();
  panel.wake_p99_history = history_.wake_p99();
  panel.wake_bins = wake_.bins();
  panel.wake_window_s = wake_.window_s();
  panel.watchdog_tripped = rs && rs->watchdog_tripped != 0;
  panel.connected = session_.link() == Link::kConnected;
  panel.can_record = !replay_;
  panel.recording = recorder_.state() != RecorderControl::State::kOff;
  panel.record_line = recorder_.panel_line();
  if (replay_) replay_panel(*replay_, clock_.speed(), clock_.paused(), panel);
  panel.view = ui_.view;
  panel.presets = preset_names_;
  panel.preset = ui_.preset;
  panel.level = ui_.level, panel.width = ui_.width;
  panel.clip = ui_.clip, panel.clip_mm = ui_.clip_mm;
  panel.show_patch = ui_.show_patch;
  if (volume_.shown()) panel.tf_editor = volume_.editor(), panel.histogram = volume_.histogram();
  if (sim().bleeding() != nullptr) panel.blood = blood_lines(*sim().bleeding());
  return panel;
}

void VizApp::do_panel_actions(const render::PanelActions& act, std::int64_t now) {
  if (act.tool >= 0) {
    Command c{};
    c.hand = ui_.hand;
    c.kind = CommandKind::kSetToolMode;
    c.mode = static_cast<ToolMode>(act.tool);
    (void)session_.send(c, now);
  }
  if (act.rearm || act.reset) {
    Command c{};
    c.hand = ui_.hand;
    c.kind = act.reset ? CommandKind::kReset : CommandKind::kRearm;
    (void)session_.send(c, now);
  }
  if (act.view >= 0) ui_.view = act.view;
  if (act.preset >= 0) ui_.preset = act.preset, ui_.level = 0, ui_.width = 1;
  if (act.window_changed) ui_.level = act.level, ui_.width = act.width;
  if (act.clip_changed) ui_.clip = act.clip, ui_.clip_mm = act.clip_mm;
  if (act.patch_toggled) ui_.show_patch = !ui_.show_patch;
  if (act.tf_edited) volume_.mark_edited();
  if (act.screenshot) want_snapshot_ = true;
  if (act.replay_pause) clock_.toggle_pause();
  if (act.replay_speed > 0) clock_.set_speed(act.replay_speed);
  if (act.record) want_record_ = true;
}

void VizApp::arm_recording(const std::string& path) {
  // An attempt starts from untouched tissue: a fresh scene.
  auto fresh = sim::SceneSim::create(sim().setup());
  if (!fresh.ok()) {
    recorder_.set_message(fresh.error().message);
    return;
  }
  sim_ = std::move(fresh).value();
  shown_revision_ = ~std::uint64_t{0};
  volume_.reset();
  recorder_.arm(path);
}

void VizApp::manage_recording() {
  if (want_record_) {  // Record: a fresh scene and the servo's reset; Stop: finish the file
    want_record_ = false;
    if (recorder_.state() != RecorderControl::State::kOff) {
      recorder_.stop();  // (armed and waiting for the reset: nothing was written yet)
    } else {
      char name[64];
      const std::time_t wall = std::time(nullptr);
      std::strftime(name, sizeof name, "lancet-%Y%m%d-%H%M%S.h5", std::localtime(&wall));
      // A trainee's station without --record records every attempt into its outbox.
      const bool outbox = station_ != nullptr && station_->records_into_outbox(o_.record_path);
      arm_recording(outbox ? station_->recording_path() : name);
    }
  }
  // lancet-rt went away while recording: with --record, the next attempt is recorded once it is
  // back, on a fresh scene.
  if (!replay_) {
    const std::string next = recorder_.after_rt_loss(session_);
    if (!next.empty()) arm_recording(next);
  }
}

void VizApp::write_snapshot() {  // lancet-YYYYmmdd-HHMMSS.png in the working directory
  want_snapshot_ = false;
  char name[64];
  const std::time_t wall = std::time(nullptr);
  std::strftime(name, sizeof name, "lancet-%Y%m%d-%H%M%S.png", std::localtime(&wall));
  const render::Image img = screen_->renderer.read_back();
  std::printf("lancet-viz: %s %s\n", render::write_png(name, img) ? "wrote" : "cannot write", name);
}

int VizApp::finish(int exit_code) {
  recorder_.stop();
  if (replay_) {
    const int verdict = print_replay_verdict(*replay_, o_.replay_path, replay_error_, o_.headless);
    exit_code = exit_code != 0 ? exit_code : verdict;
  } else {
    std::printf("lancet-viz: %llu frames, %llu samples received (%llu lost), %llu patches published\n",
                static_cast<unsigned long long>(frames_), static_cast<unsigned long long>(session_.samples_total()),
                static_cast<unsigned long long>(session_.stats().lost),
                static_cast<unsigned long long>(session_.patches_published()));
  }
  if (sim().task() != nullptr) std::printf("lancet-viz: %s\n", sim().task()->status().line.c_str());
  RunFigures run;
  run.frames = frames_;
  run.screenshot_variance = variance_;
  run.blood_ms_per_frame = frames_ > 0 ? blood_ms_ / static_cast<double>(frames_) : 0.0;
  run.screenshot = o_.screenshot;
  if (!o_.stats.empty() && !write_stats(o_.stats, session_, sim(), run)) {
    std::fprintf(stderr, "lancet-viz: cannot write stats to %s\n", o_.stats.c_str());
    exit_code = exit_code != 0 ? exit_code : 1;
  }
  return exit_code;
}

}  // namespace lancet::viz
