#include "device/usb_arm.hpp"

#include "device/joint_signals.hpp"

#include "lancet/shared_model/units.hpp"

#include <libusb.h>
#include <time.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>

namespace lancet::device {

namespace {

// How long configure() waits for the first IN report (the arm must answer).
constexpr std::int64_t kFirstReportWindowNs = 200'000'000;
// How long teardown waits for a cancelled transfer to come back.
constexpr std::int64_t kCancelWaitNs = 100'000'000;

std::string hex4(unsigned v) {
  char b[8];
  std::snprintf(b, sizeof b, "%04x", v & 0xFFFFu);
  return b;
}

std::string hex2(unsigned v) {
  char b[8];
  std::snprintf(b, sizeof b, "0x%02x", v & 0xFFu);
  return b;
}

std::string location(std::uint8_t bus, std::uint8_t address) {
  char b[40];
  std::snprintf(b, sizeof b, "bus %03u address %03u", static_cast<unsigned>(bus), static_cast<unsigned>(address));
  return b;
}

const char* type_name(std::uint8_t attributes) {
  switch (attributes & LIBUSB_TRANSFER_TYPE_MASK) {
    case LIBUSB_ENDPOINT_TRANSFER_TYPE_CONTROL: return "control";
    case LIBUSB_ENDPOINT_TRANSFER_TYPE_ISOCHRONOUS: return "isochronous";
    case LIBUSB_ENDPOINT_TRANSFER_TYPE_BULK: return "bulk";
    default: return "interrupt";
  }
}

std::int64_t type_min(arm::FieldType t) noexcept {
  switch (t) {
    case arm::FieldType::kI8: return std::numeric_limits<std::int8_t>::min();
    case arm::FieldType::kI16: return std::numeric_limits<std::int16_t>::min();
    case arm::FieldType::kI32: return std::numeric_limits<std::int32_t>::min();
    default: return 0;
  }
}

std::int64_t type_max(arm::FieldType t) noexcept {
  switch (t) {
    case arm::FieldType::kU8: return std::numeric_limits<std::uint8_t>::max();
    case arm::FieldType::kI8: return std::numeric_limits<std::int8_t>::max();
    case arm::FieldType::kU16: return std::numeric_limits<std::uint16_t>::max();
    case arm::FieldType::kI16: return std::numeric_limits<std::int16_t>::max();
    case arm::FieldType::kU32: return std::numeric_limits<std::uint32_t>::max();
    case arm::FieldType::kI32: return std::numeric_limits<std::int32_t>::max();
  }
  return 0;
}

// One value of a report field at p (field_size(t) bytes), sign-extended for signed types.
std::int64_t read_field(const std::uint8_t* p, arm::FieldType t, arm::ByteOrder order) noexcept {
  const int size = arm::field_size(t);
  std::uint64_t u = 0;
  for (int i = 0; i < size; ++i) {
    const int k = order == arm::ByteOrder::kBig ? i : size - 1 - i;  // most significant first
    u = (u << 8) | p[k];
  }
  switch (t) {
    case arm::FieldType::kI8: return static_cast<std::int8_t>(u);
    case arm::FieldType::kI16: return static_cast<std::int16_t>(u);
    case arm::FieldType::kI32: return static_cast<std::int32_t>(u);
    default: return static_cast<std::int64_t>(u);
  }
}

// Writes v (already inside the type's range) as one value of type t at p.
void write_field(std::uint8_t* p, arm::FieldType t, arm::ByteOrder order, std::int64_t v) noexcept {
  const int size = arm::field_size(t);
  auto u = static_cast<std::uint64_t>(v);
  for (int i = 0; i < size; ++i) {
    const int k = order == arm::ByteOrder::kBig ? size - 1 - i : i;  // least significant first
    p[k] = static_cast<std::uint8_t>(u & 0xFFu);
    u >>= 8;
  }
}

// raw − last on the circle of the field's width, as a signed step (the shorter way round).
std::int64_t wrapped_delta(std::int64_t raw, std::int64_t last, arm::FieldType t) noexcept {
  const int bits = 8 * arm::field_size(t);
  const std::uint64_t modulus = std::uint64_t{1} << bits;
  const std::uint64_t d = (static_cast<std::uint64_t>(raw) - static_cast<std::uint64_t>(last)) & (modulus - 1);
  return d >= modulus / 2 ? static_cast<std::int64_t>(d) - static_cast<std::int64_t>(modulus) : static_cast<std::int64_t>(d);
}

bool fits(const arm::ReportField& f, int count, std::uint32_t size) {
  return static_cast<std::uint64_t>(f.offset) + static_cast<std::uint64_t>(count) * static_cast<std::uint64_t>(arm::field_size(f.type)) <= size;
}

extern "C" void LIBUSB_CALL on_transfer_done(libusb_transfer* t) {
  // user_data is the Slot's completion flag block; see UsbArm::Slot.
  auto* done = static_cast<int*>(t->user_data);
  *done = 1;
}

}  // namespace

// --------------------------------------------------------------------------------------------
// Construction and teardown

UsbArm::UsbArm(const arm::ArmConfig& config, FaultPolicy policy)
    : Device("usb arm '" + config.name + "'", policy), config_(config), usb_(*config.usb), n_(config.joint_count()) {
  timeout_ms_ = static_cast<unsigned int>(std::max(1.0, std::ceil(usb_.timeout * 1e3 - 1e-9)));
  timeout_ns_ = static_cast<std::int64_t>(timeout_ms_) * 1'000'000;
  in_.buffer.assign(usb_.in_size, 0);
  out_.buffer.assign(usb_.out_size, 0);
  if (usb_.out_report_id) out_.buffer[0] = *usb_.out_report_id;
}

Result<std::unique_ptr<UsbArm>> UsbArm::create(const arm::ArmConfig& config, FaultPolicy policy) {
  const std::string where = config.source.empty() ? "usb arm '" + config.name + "'" : config.source;
  if (!config.usb)
    return Error{ErrorCode::kInvalid, where + ": the usb backend needs a [bus.usb] section (backend is " +
                                          (config.backend == arm::Backend::kUsb ? "usb" : "not usb") + ")"};
  const int n = config.joint_count();
  if (n < 1 || n > kMaxJoints || static_cast<int>(config.joints.size()) != n || static_cast<int>(config.actuators.size()) != n)
    return Error{ErrorCode::kInvalid, where + ": the arm needs 1.." + std::to_string(kMaxJoints) +
                                          " joints with one joint and one actuator entry each (found " + std::to_string(config.joints.size()) +
                                          " joints, " + std::to_string(config.actuators.size()) + " actuators)"};
  const auto& u = *config.usb;
  std::string bad;
  if (u.in_size < 1 || u.out_size < 1) bad = "report sizes must be at least 1 byte";
  else if (!fits(u.encoder_counts, n, u.in_size)) bad = "bus.usb.in_report.encoder_counts does not fit in the report";
  else if (u.buttons && !fits(*u.buttons, 1, u.in_size)) bad = "bus.usb.in_report.buttons does not fit in the report";
  else if (u.status && !fits(*u.status, 1, u.in_size)) bad = "bus.usb.in_report.status does not fit in the report";
  else if (!fits(u.current_command, n, u.out_size)) bad = "bus.usb.out_report.current_command does not fit in the report";
  else if (u.control && !fits(*u.control, 1, u.out_size)) bad = "bus.usb.out_report.control does not fit in the report";
  else if (!(u.current_command.lsb > 0)) bad = "bus.usb.out_report.current_command.lsb_ma must be > 0";
  else if (!(u.timeout > 0)) bad = "bus.usb.timeout_ms must be > 0";
  if (!bad.empty()) return Error{ErrorCode::kInvalid, where + ": " + bad};
  return std::unique_ptr<UsbArm>(new UsbArm(config, policy));
}

UsbArm::~UsbArm() {
  if (handle_ != nullptr && claimed_ && !lost_ && enabled_) (void)send_control(false);
  close_device();
  // A transfer still in flight after close_device() belongs to libusb until it is called back:
  // leak it rather than free memory libusb may still write (does not happen with a live bus).
  if (in_.transfer != nullptr && !in_.in_flight) libusb_free_transfer(in_.transfer);
  if (out_.transfer != nullptr && !out_.in_flight) libusb_free_transfer(out_.transfer);
  if (ctx_ != nullptr) libusb_exit(ctx_);
}

std::string UsbArm::device_location() const { return handle_ == nullptr ? std::string() : location(bus_number_, address_); }

void UsbArm::set_velocity_cutoff_hz(double hz) noexcept { velocity_.set_cutoff_hz(hz); }

void UsbArm::reset_estimator() noexcept {
  have_sample_ = false;
  last_raw_.fill(0);
  counts_.fill(0);
  velocity_.reset();
}

// --------------------------------------------------------------------------------------------
// Opening the device (not real-time)

Outcome UsbArm::open_and_claim() {
  const std::string id = hex4(usb_.vid) + ":" + hex4(usb_.pid);
  libusb_device** list = nullptr;
  const ssize_t count = libusb_get_device_list(ctx_, &list);
  if (count < 0)
    return Outcome::failure(ErrorCode::kSystem, name() + ": cannot list USB devices: " + libusb_strerror(static_cast<int>(count)));
  libusb_device* found = nullptr;
  std::string seen;
  for (ssize_t i = 0; i < count; ++i) {
    libusb_device_descriptor d{};
    if (libusb_get_device_descriptor(list[i], &d) != 0) continue;
    const std::string here = hex4(d.idVendor) + ":" + hex4(d.idProduct) + " at " +
                             location(libusb_get_bus_number(list[i]), libusb_get_device_address(list[i]));
    seen += (seen.empty() ? "" : ", ") + here;
    if (found == nullptr && d.idVendor == usb_.vid && d.idProduct == usb_.pid) found = list[i];
  }
  if (found == nullptr) {
    libusb_free_device_list(list, 1);
    return Outcome::failure(ErrorCode::kNotFound,
                            name() + ": no USB device " + id + " (bus.usb vid/pid in " + config_.source + "); " +
                                (seen.empty() ? std::string("no USB devices are visible at all (is /dev/bus/usb there? a container needs the device passed through)")
                                              : "devices seen: " + seen));
  }
  bus_number_ = libusb_get_bus_number(found);
  address_ = libusb_get_device_address(found);
  const std::string at = name() + ": " + id + " at " + location(bus_number_, address_);

  // The endpoints must exist on the interface, with the configured direction and type.
  libusb_config_descriptor* cd = nullptr;
  int r = libusb_get_active_config_descriptor(found, &cd);
  if (r != 0) {
    libusb_free_device_list(list, 1);
    return Outcome::failure(ErrorCode::kSystem, at + ": cannot read the active configuration: " + libusb_strerror(r));
  }
  std::string problem;
  const libusb_interface_descriptor* alt = nullptr;
  for (int i = 0; i < cd->bNumInterfaces && alt == nullptr; ++i) {
    const libusb_interface& itf = cd->interface[i];
    if (itf.num_altsetting > 0 && itf.altsetting[0].bInterfaceNumber == usb_.interface_number) alt = &itf.altsetting[0];
  }
  if (alt == nullptr) {
    problem = "the active configuration has no interface " + std::to_string(usb_.interface_number) + " (bus.usb.interface)";
  } else {
    std::string eps;
    bool have_in = false, have_out = false;
    for (int e = 0; e < alt->bNumEndpoints; ++e) {
      const libusb_endpoint_descriptor& ep = alt->endpoint[e];
      eps += (eps.empty() ? "" : ", ") + hex2(ep.bEndpointAddress) + " " + type_name(ep.bmAttributes) +
             ((ep.bEndpointAddress & LIBUSB_ENDPOINT_IN) != 0 ? " IN" : " OUT");
      const bool interrupt = (ep.bmAttributes & LIBUSB_TRANSFER_TYPE_MASK) == LIBUSB_ENDPOINT_TRANSFER_TYPE_INTERRUPT;
      if (ep.bEndpointAddress == usb_.endpoint_in) have_in = interrupt;
      if (ep.bEndpointAddress == usb_.endpoint_out) have_out = interrupt;
    }
    if (!have_in || !have_out)
      problem = "interface " + std::to_string(usb_.interface_number) + " needs interrupt IN endpoint " + hex2(usb_.endpoint_in) +
                " and interrupt OUT endpoint " + hex2(usb_.endpoint_out) + " (bus.usb.endpoint_in/out); it has: " +
                (eps.empty() ? std::string("no endpoints") : eps);
  }
  libusb_free_config_descriptor(cd);
  if (!problem.empty()) {
    libusb_free_device_list(list, 1);
    return Outcome::failure(ErrorCode::kMismatch, at + ": " + problem);
  }

  r = libusb_open(found, &handle_);
  libusb_free_device_list(list, 1);
  if (r != 0) {
    handle_ = nullptr;
    std::string hint;
    if (r == LIBUSB_ERROR_ACCESS) hint = " (no permission on the device node: add a udev rule giving your user access to " + id + ")";
    return Outcome::failure(r == LIBUSB_ERROR_NO_DEVICE ? ErrorCode::kNotFound : ErrorCode::kSystem,
                            at + ": cannot open: " + libusb_strerror(r) + hint);
  }
  lost_ = false;

  // A HID-class arm is bound to usbhid by the kernel: take the interface from it.
  r = libusb_kernel_driver_active(handle_, usb_.interface_number);
  if (r == 1) {
    r = libusb_detach_kernel_driver(handle_, usb_.interface_number);
    if (r != 0 && r != LIBUSB_ERROR_NOT_FOUND) {
      close_device();
      return Outcome::failure(ErrorCode::kInUse, at + ": cannot detach the kernel driver from interface " +
                                                     std::to_string(usb_.interface_number) + ": " + libusb_strerror(r));
    }
    detached_driver_ = detached_driver_ || r == 0;
  }
  r = libusb_claim_interface(handle_, usb_.interface_number);
  if (r != 0) {
    const std::string why = r == LIBUSB_ERROR_BUSY ? " (another program or driver holds it)" : "";
    close_device();
    return Outcome::failure(r == LIBUSB_ERROR_BUSY ? ErrorCode::kInUse : ErrorCode::kSystem,
                            at + ": cannot claim interface " + std::to_string(usb_.interface_number) + ": " + libusb_strerror(r) + why);
  }
  claimed_ = true;

  // The transfers are allocated once and re-pointed at each new handle.
  for (Slot* s : {&in_, &out_}) {
    if (s->transfer == nullptr || s->in_flight) {
      s->transfer = libusb_alloc_transfer(0);  // a stuck old one is left to libusb (see ~UsbArm)
      s->in_flight = false;
      if (s->transfer == nullptr) {
        close_device();
        return Outcome::failure(ErrorCode::kSystem, at + ": cannot allocate a libusb transfer");
      }
    }
  }
  libusb_fill_interrupt_transfer(in_.transfer, handle_, usb_.endpoint_in, in_.buffer.data(), static_cast<int>(usb_.in_size),
                                 on_transfer_done, &in_.completed, timeout_ms_);
  libusb_fill_interrupt_transfer(out_.transfer, handle_, usb_.endpoint_out, out_.buffer.data(), static_cast<int>(usb_.out_size),
                                 on_transfer_done, &out_.completed, timeout_ms_);
  return Outcome::success();
}

void UsbArm::close_device() noexcept {
  if (handle_ == nullptr) return;
  for (Slot* s : {&in_, &out_}) {
    if (!s->in_flight) continue;
    (void)libusb_cancel_transfer(s->transfer);
    pump_until(*s, monotonic_ns() + kCancelWaitNs);
  }
  if (claimed_ && !lost_) (void)libusb_release_interface(handle_, usb_.interface_number);
  claimed_ = false;
  if (detached_driver_ && !lost_) (void)libusb_attach_kernel_driver(handle_, usb_.interface_number);
  detached_driver_ = false;
  libusb_close(handle_);
  handle_ = nullptr;
}

Outcome UsbArm::send_control(bool enable) {
  enabled_ = enable;
  encode_out(nullptr, enable);
  IoStatus s = transfer(out_, usb_.endpoint_out);
  if (s == IoStatus::kOk && out_.actual_length != static_cast<int>(usb_.out_size)) s = IoStatus::kProtocolError;
  if (s == IoStatus::kOk) return Outcome::success();
  return Outcome::failure(s == IoStatus::kDisconnected ? ErrorCode::kNotFound : ErrorCode::kSystem,
                          name() + ": sending the " + (enable ? "enable" : "disable") + " report (zero currents) to " +
                              location(bus_number_, address_) + " failed: " + to_string(s) +
                              (s == IoStatus::kTimeout ? " after " + std::to_string(timeout_ms_) + " ms" : std::string()));
}

// --------------------------------------------------------------------------------------------
// Lifecycle hooks

Outcome UsbArm::on_configure() {
  Outcome o = reopen();  // a fresh context each attempt: a retry sees a newly plugged arm
  if (!o.ok()) return o;

  // The arm must answer: wait a little for one well-formed IN report.
  const std::int64_t until = monotonic_ns() + std::max(kFirstReportWindowNs, 10 * timeout_ns_);
  IoStatus s = IoStatus::kTimeout;
  do {
    s = transfer(in_, usb_.endpoint_in);
    if (s == IoStatus::kOk && in_.actual_length != static_cast<int>(usb_.in_size)) {
      close_device();
      return Outcome::failure(ErrorCode::kMismatch, name() + ": the first IN report from " + location(bus_number_, address_) + " has " +
                                                        std::to_string(in_.actual_length) + " bytes, expected " +
                                                        std::to_string(usb_.in_size) + " (bus.usb.in_report.size)");
    }
    if (s == IoStatus::kOk && usb_.in_report_id && in_.buffer[0] != *usb_.in_report_id) {
      close_device();
      return Outcome::failure(ErrorCode::kMismatch, name() + ": the first IN report from " + location(bus_number_, address_) +
                                                        " has report id " + std::to_string(in_.buffer[0]) + ", expected " +
                                                        std::to_string(*usb_.in_report_id) + " (bus.usb.in_report.report_id)");
    }
  } while (s == IoStatus::kTimeout && monotonic_ns() < until);
  if (s != IoStatus::kOk) {
    close_device();
    return Outcome::failure(ErrorCode::kNotReady, name() + ": the arm at " + location(bus_number_, address_) +
                                                      " does not answer: no IN report on " + hex2(usb_.endpoint_in) + " (" + to_string(s) + ")");
  }
  return Outcome::success();
}

Outcome UsbArm::reopen() {
  // A fresh context: its scan finds the arm wherever it came back, even if a hotplug event was
  // missed.
  close_device();
  if (ctx_ != nullptr) libusb_exit(ctx_);
  ctx_ = nullptr;
  const int r = libusb_init(&ctx_);
  if (r != 0) {
    ctx_ = nullptr;
    return Outcome::failure(ErrorCode::kSystem, name() + ": libusb_init failed: " + libusb_strerror(r));
  }
  return open_and_claim();
}

Outcome UsbArm::on_activate() {
  reset_estimator();
  if (handle_ == nullptr || lost_) {
    Outcome o = reopen();
    if (!o.ok()) return o;
  } else if (!claimed_) {
    const int r = libusb_claim_interface(handle_, usb_.interface_number);
    if (r != 0)
      return Outcome::failure(ErrorCode::kInUse, name() + ": cannot claim interface " + std::to_string(usb_.interface_number) +
                                                     " again: " + libusb_strerror(r));
    claimed_ = true;
  }
  return send_control(true);
}

Outcome UsbArm::on_deactivate() {
  if (handle_ == nullptr || lost_) {
    enabled_ = false;
    return Outcome::success();  // nothing left to drive
  }
  // The interface stays claimed: read() works while inactive (probing, monitoring); it is
  // released when the UsbArm goes.
  return claimed_ ? send_control(false) : Outcome::success();
}

Outcome UsbArm::on_rearm() {
  reset_estimator();
  if (handle_ != nullptr && !lost_ && claimed_) {
    Outcome o = send_control(true);
    // Only a bus error (gone, I/O) is worth a reopen; a timeout or a bad reply is reported.
    if (o.ok() || o.error->code != ErrorCode::kNotFound) return o;
  }
  Outcome o = reopen();
  if (!o.ok()) return o;
  return send_control(true);
}

// --------------------------------------------------------------------------------------------
// Transfers (real-time path)

void UsbArm::pump_until(Slot& slot, std::int64_t deadline_ns) noexcept {
  while (slot.completed == 0) {
    const std::int64_t left = deadline_ns - monotonic_ns();
    if (left <= 0) return;
    timeval tv{};
    tv.tv_sec = static_cast<time_t>(left / 1'000'000'000);
    tv.tv_usec = static_cast<suseconds_t>((left % 1'000'000'000) / 1000);
    const int r = libusb_handle_events_timeout_completed(ctx_, &tv, &slot.completed);
    if (r != 0 && r != LIBUSB_ERROR_INTERRUPTED && r != LIBUSB_ERROR_TIMEOUT) return;
  }
  if (slot.completed != 0 && slot.in_flight) {
    slot.in_flight = false;
    slot.status = slot.transfer->status;
    slot.actual_length = slot.transfer->actual_length;
    slot.done_ns = monotonic_ns();
  }
}

IoStatus UsbArm::finish_in_flight(Slot& slot) noexcept {
  pump_until(slot, monotonic_ns() + 1);  // whatever libusb has already: do not wait
  if (slot.in_flight) return IoStatus::kTimeout;
  ++stats_.completed;
  return IoStatus::kOk;  // the late result is dropped: it belongs to an earlier tick
}

IoStatus UsbArm::transfer(Slot& slot, unsigned char endpoint) noexcept {
  if (slot.in_flight && finish_in_flight(slot) != IoStatus::kOk) return lost_ ? IoStatus::kDisconnected : IoStatus::kTimeout;
  slot.completed = 0;
  slot.actual_length = 0;
  const int r = libusb_submit_transfer(slot.transfer);
  if (r != 0) return status_from_error(r);
  ++stats_.submitted;
  slot.in_flight = true;
  // libusb cancels the transfer itself after timeout_ms_; the margin covers the cancellation.
  const std::int64_t margin = std::max<std::int64_t>(timeout_ns_, 1'000'000);
  pump_until(slot, monotonic_ns() + timeout_ns_ + margin);
  if (slot.in_flight) {
    // The cancellation did not come back in time (a reply that never arrives, not even as an
    // error): cancel again and give it one more margin; then leave it for a later call.
    const int c = libusb_cancel_transfer(slot.transfer);
    if (c == LIBUSB_ERROR_NO_DEVICE) lost_ = true;
    pump_until(slot, monotonic_ns() + margin);
    if (slot.in_flight) {
      ++stats_.cancelled_late;
      return lost_ ? IoStatus::kDisconnected : IoStatus::kTimeout;
    }
  }
  ++stats_.completed;
  return status_from_completion(slot, endpoint);
}

IoStatus UsbArm::status_from_completion(Slot& slot, unsigned char endpoint) noexcept {
  switch (slot.status) {
    case LIBUSB_TRANSFER_COMPLETED: return IoStatus::kOk;
    case LIBUSB_TRANSFER_TIMED_OUT:
    case LIBUSB_TRANSFER_CANCELLED: return IoStatus::kTimeout;
    case LIBUSB_TRANSFER_NO_DEVICE: lost_ = true; return IoStatus::kDisconnected;
    case LIBUSB_TRANSFER_ERROR: return IoStatus::kDisconnected;  // LIBUSB_ERROR_IO
    case LIBUSB_TRANSFER_OVERFLOW: return IoStatus::kProtocolError;
    case LIBUSB_TRANSFER_STALL: {
      ++stats_.clear_halts;
      const int r = libusb_clear_halt(handle_, endpoint);
      if (r == 0) return IoStatus::kProtocolError;
      if (r == LIBUSB_ERROR_NO_DEVICE) lost_ = true;
      return IoStatus::kDisconnected;
    }
    default: return IoStatus::kProtocolError;
  }
}

IoStatus UsbArm::status_from_error(int e) noexcept {
  switch (e) {
    case LIBUSB_ERROR_TIMEOUT:
    case LIBUSB_ERROR_BUSY: return IoStatus::kTimeout;
    case LIBUSB_ERROR_NO_DEVICE: lost_ = true; return IoStatus::kDisconnected;
    case LIBUSB_ERROR_IO:
    case LIBUSB_ERROR_PIPE: return IoStatus::kDisconnected;
    default: return IoStatus::kProtocolError;
  }
}

void UsbArm::encode_out(const JointCommand* cmd, bool enable) noexcept {
  const arm::ReportField& f = usb_.current_command;
  const int size = arm::field_size(f.type);
  const double lo = static_cast<double>(type_min(f.type)), hi = static_cast<double>(type_max(f.type));
  for (int j = 0; j < n_; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    double tau = cmd != nullptr && j < cmd->n ? cmd->tau[uj] : 0.0;
    if (!std::isfinite(tau)) tau = 0.0;
    const double peak = config_.actuators[uj].peak_current;
    const double amps = std::clamp(arm::motor_current_for_joint_torque(config_.joints[uj], config_.actuators[uj], tau), -peak, peak);
    const double counts = std::clamp(std::nearbyint(amps / f.lsb), lo, hi);
    write_field(out_.buffer.data() + f.offset + static_cast<std::size_t>(j * size), f.type, usb_.byte_order, static_cast<std::int64_t>(counts));
  }
  if (usb_.control) write_field(out_.buffer.data() + usb_.control->offset, usb_.control->type, usb_.byte_order, enable ? 1 : 0);
}

IoStatus UsbArm::on_read(JointState& out) noexcept {
  if (handle_ == nullptr || lost_ || !claimed_) return IoStatus::kDisconnected;
  const IoStatus s = transfer(in_, usb_.endpoint_in);
  if (s != IoStatus::kOk) return s;
  if (in_.actual_length != static_cast<int>(usb_.in_size)) return IoStatus::kProtocolError;
  const std::uint8_t* b = in_.buffer.data();
  if (usb_.in_report_id && b[0] != *usb_.in_report_id) return IoStatus::kProtocolError;

  // The report is well formed: decode it and update the estimator.
  const arm::ReportField& ef = usb_.encoder_counts;
  const int size = arm::field_size(ef.type);
  const std::int64_t t = in_.done_ns;
  out.n = n_;
  for (int j = 0; j < n_; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const std::int64_t raw = read_field(b + ef.offset + static_cast<std::size_t>(j * size), ef.type, usb_.byte_order);
    counts_[uj] = have_sample_ ? counts_[uj] + wrapped_delta(raw, last_raw_[uj], ef.type) : raw;
    last_raw_[uj] = raw;
    out.q[uj] = arm::joint_position_from_counts(config_.joints[uj], counts_[uj]);
    out.counts[uj] = counts_[uj];
  }
  velocity_.update(n_, out.q, t, out.qd);
  have_sample_ = true;

  std::uint32_t word = 0;
  if (usb_.buttons) word = static_cast<std::uint32_t>(read_field(b + usb_.buttons->offset, usb_.buttons->type, usb_.byte_order));
  out.buttons = pressed_buttons(config_.buttons, word);
  out.status = usb_.status ? static_cast<std::uint32_t>(read_field(b + usb_.status->offset, usb_.status->type, usb_.byte_order)) : 0u;
  return (out.status & 1u) != 0 ? IoStatus::kDeviceFault : IoStatus::kOk;
}

IoStatus UsbArm::on_write(const JointCommand& cmd) noexcept {
  if (handle_ == nullptr || lost_ || !claimed_) return IoStatus::kDisconnected;
  encode_out(&cmd, enabled_);
  const IoStatus s = transfer(out_, usb_.endpoint_out);
  if (s == IoStatus::kOk && out_.actual_length != static_cast<int>(usb_.out_size)) return IoStatus::kProtocolError;
  return s;
}

}  // namespace lancet::device
