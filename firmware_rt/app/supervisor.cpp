#include "app/supervisor.hpp"

#include <algorithm>
#include <cinttypes>
#include <cstdio>

#include "device/device.hpp"
#include "rt/watchdog.hpp"
#include "text/text.hpp"

namespace lancet::app {

namespace {

using text::format;

bool faulted(const HandStatus& s) { return s.device_state == device::Lifecycle::kFault; }

}  // namespace

std::string describe_arm(const HandStatus& st) {
  if (st.has_arm == 0) return "built-in simulated stylus";
  const auto state = st.device_state;
  std::string s = device::to_string(state);
  if (state == device::Lifecycle::kFault) {
    s += format(" (%s)", device::to_string(st.device_fault_cause));
    // The backends' words name the node and decode the code; the numbers alone only when there
    // are no words (they stay in the status and the stats for programs).
    if (st.fault_text[0] != '\0') {
      s += std::string(": ") + st.fault_text;
    } else {
      if (st.fault_node >= 0) s += format(" [node %d]", st.fault_node);
      if (st.fault_code != 0) s += format(" [code 0x%04" PRIX32 "]", st.fault_code);
    }
  }
  if (st.link_lost != 0) s += "; bus link lost (reconnecting)";
  return s;
}

std::string describe_bus(const BusCounters& b) {
  return format("%llu reads, %llu writes, %llu timeouts, %llu crc, %llu protocol, %llu disconnects, %llu drive faults, "
             "%llu glitches, %llu stale replies, %llu faults, %llu reconnects, slowest I/O %.0f us",
             static_cast<unsigned long long>(b.reads), static_cast<unsigned long long>(b.writes),
             static_cast<unsigned long long>(b.timeouts), static_cast<unsigned long long>(b.crc_errors),
             static_cast<unsigned long long>(b.protocol_errors), static_cast<unsigned long long>(b.disconnects),
             static_cast<unsigned long long>(b.device_faults), static_cast<unsigned long long>(b.glitches),
             static_cast<unsigned long long>(b.stale_replies), static_cast<unsigned long long>(b.faults),
             static_cast<unsigned long long>(b.reconnects), static_cast<double>(b.max_io_ns) / 1e3);
}

RtSupervisor::RtSupervisor(RtServo& servo, SupervisorParams params, std::int64_t start_ns)
    : servo_(servo), params_(std::move(params)), start_ns_(start_ns), tick_seen_at_ns_(start_ns) {}

std::vector<std::string> RtSupervisor::poll(std::int64_t now_ns) {
  std::vector<std::string> out;
  const std::int64_t job_from = monotonic_ns();
  if (servo_.supervise(now_ns)) {
    // The outcome is announced from the status (below) once the servo has taken the device back.
  }
  // A device job (a re-arm, a reconnect) blocks supervise() for as long as it takes: what follows
  // happens that much later. Without this, a tick seen right after a job longer than the stall
  // timeout was stamped with the time before the job, and the next poll took the job's duration
  // for a servo that did not tick.
  now_ns += monotonic_ns() - job_from;
  RtStatus st{};
  if (servo_.read_status(st) == ReadStatus::kOk) {
    if (have_) compare(last_, st, now_ns, out);
    for (std::size_t h = 0; !have_ && h < st.hands && h < kHandCount; ++h) {
      if (st.hand[h].has_arm != 0 && faulted(st.hand[h]))
        out.push_back(std::string(hand_name(static_cast<Hand>(h))) + " arm: FAULT on " + params_.arm_name[h] + ": " + describe_arm(st.hand[h]));
    }
    last_ = st;
    have_ = true;
  }
  // Is the servo still ticking?
  if (have_ && last_.tick != tick_seen_) {
    tick_seen_ = last_.tick;
    tick_seen_at_ns_ = now_ns;
  }
  const std::int64_t allowed = params_.stall_timeout_ns + (tick_seen_ == 0 ? params_.first_tick_grace_ns : 0);
  if (!stalled_ && now_ns - tick_seen_at_ns_ > allowed) {
    stalled_ = true;
    out.push_back(format("SERVO STALLED: no tick for %.0f ms (last tick %llu): ending lancet-rt; the arm's own watchdog "
                      "takes its torque off",
                      static_cast<double>(now_ns - tick_seen_at_ns_) / 1e6, static_cast<unsigned long long>(tick_seen_)));
  }
  return out;
}

void RtSupervisor::compare(const RtStatus& a, const RtStatus& b, std::int64_t now_ns, std::vector<std::string>& out) {
  const std::size_t hands = std::min<std::size_t>(b.hands, kHandCount);
  for (std::size_t h = 0; h < hands; ++h) {
    const HandStatus& ha = a.hand[h];
    const HandStatus& hb = b.hand[h];
    if (hb.has_arm == 0) continue;
    const char* const hand = hand_name(static_cast<Hand>(h));
    const std::string who = std::string(hand) + " arm: ";  // every line about an arm says whose
    const std::string& arm = params_.arm_name[h];
    const std::string rearm_hint = "lancetctl rearm --rt " + params_.shm_name + " --hand " + hand;
    if (!faulted(ha) && faulted(hb)) {
      out.push_back(who + "FAULT on " + arm + ": " + describe_arm(hb) + ". Its force held at zero until re-armed: " + rearm_hint +
                    " (or W in the viz)");
    }
    if (faulted(ha) && !faulted(hb)) out.push_back(who + arm + " re-armed: " + describe_arm(hb));
    if (ha.link_lost == 0 && hb.link_lost != 0) {
      link_lost_at_ns_[h] = now_ns;
      out.push_back(who + arm + ": bus link lost; reconnecting every second (the arm stays faulted until re-armed)");
    }
    if (hb.bus.reconnects > ha.bus.reconnects) {
      out.push_back(who + format("%s: bus link back after %.1f s; re-arm to resume: %s", arm.c_str(),
                                 static_cast<double>(now_ns - link_lost_at_ns_[h]) / 1e9, rearm_hint.c_str()));
    } else if (hb.link_lost != 0 && std::string_view(hb.rearm_text) != std::string_view(ha.rearm_text) && hb.rearm_text[0] != '\0') {
      // A reconnect attempt failed with a new reason: say it once, not every second.
      out.push_back(who + arm + ": reconnect failed: " + hb.rearm_text);
    }
    if (hb.rearm_failures > ha.rearm_failures) out.push_back(who + arm + ": re-arm failed: " + hb.rearm_text);
  }
  if (a.watchdog_tripped == 0 && b.watchdog_tripped != 0) {
    out.push_back(format("WATCHDOG TRIPPED (%s): every hand's force held at zero until re-armed: lancetctl rearm --rt %s (or W in the viz)",
                      rt::to_string(b.watchdog_reason), params_.shm_name.c_str()));
  }
  if (a.watchdog_tripped != 0 && b.watchdog_tripped == 0) out.push_back("watchdog re-armed");
  if (b.operator_requests > a.operator_requests) out.push_back("re-arm requested by an operator (lancetctl rearm)");
  if (a.viz_alive == 0 && b.viz_alive != 0) out.push_back("lancet-viz is publishing tissue: force enabled");
  if (a.viz_alive != 0 && b.viz_alive == 0) out.push_back("lancet-viz stopped beating: fading the force out");

  // Rate-limited summaries.
  if (now_ns < next_summary_ns_) return;
  const SegmentHealth& h = b.health;
  const SegmentHealth& r = health_reported_;
  const std::uint64_t rej = h.commands_rejected - r.commands_rejected, pat = h.patches_rejected - r.patches_rejected,
                      tar = h.targets_rejected - r.targets_rejected, rr = h.ring_resets - r.ring_resets,
                      sr = h.sample_ring_resets - r.sample_ring_resets, def = h.commands_deferred - r.commands_deferred,
                      unr = h.patches_unreadable - r.patches_unreadable;
  bool said = false;
  if (rej + pat + tar + rr + sr + def + unr > 0) {
    const char* why = servo_.data().last_reject.load(std::memory_order_relaxed);
    out.push_back(format("shared segment: rejected %llu commands, %llu patches, %llu stylus targets; %llu patch reads got no "
                      "whole copy; reset the command ring %llu and the sample ring %llu times; %llu ticks left commands "
                      "queued (last: %s)",
                      static_cast<unsigned long long>(rej), static_cast<unsigned long long>(pat),
                      static_cast<unsigned long long>(tar), static_cast<unsigned long long>(unr),
                      static_cast<unsigned long long>(rr), static_cast<unsigned long long>(sr),
                      static_cast<unsigned long long>(def), why != nullptr ? why : "-"));
    health_reported_ = h;
    said = true;
  }
  for (std::size_t k = 0; k < hands; ++k) {
    const HandStatus& hb = b.hand[k];
    if (hb.bus.glitches > glitches_reported_[k]) {
      out.push_back(format("%s arm: %s: %llu encoder glitches (last: %s)", hand_name(static_cast<Hand>(k)), params_.arm_name[k].c_str(),
                           static_cast<unsigned long long>(hb.bus.glitches - glitches_reported_[k]), hb.error_text));
      glitches_reported_[k] = hb.bus.glitches;
      said = true;
    }
  }
  if (said) next_summary_ns_ = now_ns + params_.summary_interval_ns;
}

}  // namespace lancet::app
