#include "device/usb_arm.hpp"

#include "device/joint_signals.hpp"

#include "lancet/shared_model/units.hpp"

#include <libusb.h>
#include <time.h>

#include <algorithm>
#include <bit>
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
// How long activate / rearm wait for the status bits to settle.
constexpr std::int64_t kSettleNs = 200'000'000;

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
    case arm::FieldType::kU32:
    case arm::FieldType::kF32: return std::numeric_limits<std::uint32_t>::max();
    case arm::FieldType::kI32: return std::numeric_limits<std::int32_t>::max();
  }
  return 0;
}

// The field's bytes at p as an unsigned number, most significant first per its byte order.
std::uint32_t read_bits(const std::uint8_t* p, arm::FieldType t, arm::ByteOrder order) noexcept {
  const int size = arm::field_size(t);
  std::uint32_t u = 0;
  for (int i = 0; i < size; ++i) {
    const int k = order == arm::ByteOrder::kBig ? i : size - 1 - i;  // most significant first
    u = (u << 8) | p[k];
  }
  return u;
}

void write_bits(std::uint8_t* p, arm::FieldType t, arm::ByteOrder order, std::uint32_t u) noexcept {
  const int size = arm::field_size(t);
  for (int i = 0; i < size; ++i) {
    const int k = order == arm::ByteOrder::kBig ? size - 1 - i : i;  // least significant first
    p[k] = static_cast<std::uint8_t>(u & 0xFFu);
    u >>= 8;
  }
}

// One integer value of a report field at p, sign-extended for signed types (not for kF32).
std::int64_t read_field(const std::uint8_t* p, arm::FieldType t, arm::ByteOrder order) noexcept {
  const std::uint32_t u = read_bits(p, t, order);
  switch (t) {
    case arm::FieldType::kI8: return static_cast<std::int8_t>(u);
    case arm::FieldType::kI16: return static_cast<std::int16_t>(u);
    case arm::FieldType::kI32: return static_cast<std::int32_t>(u);
    default: return static_cast<std::int64_t>(u);
  }
}

// Writes raw as one value of type t at p: integers rounded and clamped to the type's range (NaN:
// 0), f32 as the nearest float. Returns the value written.
double write_value(std::uint8_t* p, arm::FieldType t, arm::ByteOrder order, double raw) noexcept {
  if (t == arm::FieldType::kF32) {
    const float f = std::isfinite(raw) ? static_cast<float>(std::clamp(raw, -3.0e38, 3.0e38)) : 0.0F;
    write_bits(p, t, order, std::bit_cast<std::uint32_t>(f));
    return f;
  }
  const double v = std::isnan(raw) ? 0.0 : std::clamp(std::nearbyint(raw), static_cast<double>(type_min(t)), static_cast<double>(type_max(t)));
  write_bits(p, t, order, static_cast<std::uint32_t>(static_cast<std::uint64_t>(static_cast<std::int64_t>(v)) & 0xFFFF'FFFFu));
  return v;
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
  enable_word_ = usb_.enable_off;
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
  const auto word = [](const std::optional<arm::ReportField>& f) {
    return !f || f->type == arm::FieldType::kU8 || f->type == arm::FieldType::kU16 || f->type == arm::FieldType::kU32;
  };
  if (u.in_size < 1 || u.out_size < 1) bad = "report sizes must be at least 1 byte";
  else if (!fits(u.encoder_counts, n, u.in_size)) bad = "bus.usb.in_report.encoder_counts does not fit in the report";
  else if (u.buttons && !fits(*u.buttons, 1, u.in_size)) bad = "bus.usb.in_report.buttons does not fit in the report";
  else if (u.status && !fits(*u.status, 1, u.in_size)) bad = "bus.usb.in_report.status does not fit in the report";
  else if (!fits(u.setpoint, n, u.out_size)) bad = "bus.usb.out_report setpoint (current_command / torque_command) does not fit in the report";
  else if (u.enable && !fits(*u.enable, 1, u.out_size)) bad = "bus.usb.out_report.enable does not fit in the report";
  else if (u.fault_reset && !fits(*u.fault_reset, 1, u.out_size)) bad = "bus.usb.out_report.fault_reset does not fit in the report";
  else if (u.heartbeat && !fits(*u.heartbeat, 1, u.out_size)) bad = "bus.usb.out_report.heartbeat does not fit in the report";
  else if (!word(u.buttons) || !word(u.status) || !word(u.enable) || !word(u.fault_reset) || !word(u.heartbeat))
    bad = "bus.usb: buttons, status, enable, fault_reset and heartbeat must be u8, u16 or u32";
  else if (!(u.setpoint.scale > 0) || !(u.encoder_counts.scale > 0) || !std::isfinite(u.setpoint.bias) || !std::isfinite(u.encoder_counts.bias))
    bad = "bus.usb: scale must be > 0 and bias finite";
  else if (!(u.timeout > 0)) bad = "bus.usb.timeout_ms must be > 0";
  if (!bad.empty()) return Error{ErrorCode::kInvalid, where + ": " + bad};
  return std::unique_ptr<UsbArm>(new UsbArm(config, policy));
}

UsbArm::~UsbArm() {
  if (handle_ != nullptr && claimed_ && !lost_ && enable_word_ != usb_.enable_off) (void)send_report(usb_.enable_off, false, "the disable report");
  close_device();
  // A transfer still in flight after close_device() belongs to libusb until it is called back:
  // leak it rather than free memory libusb may still write (does not happen with a live bus).
  if (in_.transfer != nullptr && !in_.in_flight) libusb_free_transfer(in_.transfer);
  if (out_.transfer != nullptr && !out_.in_flight) libusb_free_transfer(out_.transfer);
  if (ctx_ != nullptr) libusb_exit(ctx_);
}

std::string UsbArm::device_location() const { return handle_ == nullptr ? std::string() : location(bus_number_, address_); }

void UsbArm::set_velocity_cutoff_hz(double hz) noexcept { velocity_.set_cutoff_hz(hz); }

void UsbArm::set_timeout(double seconds) noexcept {
  if (!(seconds > 0) || !std::isfinite(seconds)) return;
  timeout_ms_ = static_cast<unsigned int>(std::clamp(std::ceil(seconds * 1e3 - 1e-9), 1.0, 3'600'000.0));
  timeout_ns_ = static_cast<std::int64_t>(timeout_ms_) * 1'000'000;
}

void UsbArm::reset_estimator() noexcept {
  have_sample_ = false;
  last_raw_.fill(0);
  raw_.fill(0);
  velocity_.reset();
}

// --------------------------------------------------------------------------------------------
// Opening the device (not real-time)

Result<void> UsbArm::open_and_claim() {
  const std::string id = hex4(usb_.vid) + ":" + hex4(usb_.pid);
  libusb_device** list = nullptr;
  const ssize_t count = libusb_get_device_list(ctx_, &list);
  if (count < 0)
    return Result<void>::failure(ErrorCode::kSystem, name() + ": cannot list USB devices: " + libusb_strerror(static_cast<int>(count)));
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
    return Result<void>::failure(ErrorCode::kNotFound,
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
    return Result<void>::failure(ErrorCode::kSystem, at + ": cannot read the active configuration: " + libusb_strerror(r));
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
    return Result<void>::failure(ErrorCode::kMismatch, at + ": " + problem);
  }

  r = libusb_open(found, &handle_);
  libusb_free_device_list(list, 1);
  if (r != 0) {
    handle_ = nullptr;
    std::string hint;
    if (r == LIBUSB_ERROR_ACCESS) hint = " (no permission on the device node: add a udev rule giving your user access to " + id + ")";
    return Result<void>::failure(r == LIBUSB_ERROR_NO_DEVICE ? ErrorCode::kNotFound : ErrorCode::kSystem,
                            at + ": cannot open: " + libusb_strerror(r) + hint);
  }
  lost_ = false;

  // A HID-class arm is bound to usbhid by the kernel: take the interface from it.
  r = libusb_kernel_driver_active(handle_, usb_.interface_number);
  if (r == 1) {
    r = libusb_detach_kernel_driver(handle_, usb_.interface_number);
    if (r != 0 && r != LIBUSB_ERROR_NOT_FOUND) {
      close_device();
      return Result<void>::failure(ErrorCode::kInUse, at + ": cannot detach the kernel driver from interface " +
                                                     std::to_string(usb_.interface_number) + ": " + libusb_strerror(r));
    }
    detached_driver_ = detached_driver_ || r == 0;
  }
  r = libusb_claim_interface(handle_, usb_.interface_number);
  if (r != 0) {
    const std::string why = r == LIBUSB_ERROR_BUSY ? " (another program or driver holds it)" : "";
    close_device();
    return Result<void>::failure(r == LIBUSB_ERROR_BUSY ? ErrorCode::kInUse : ErrorCode::kSystem,
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
        return Result<void>::failure(ErrorCode::kSystem, at + ": cannot allocate a libusb transfer");
      }
    }
  }
  libusb_fill_interrupt_transfer(in_.transfer, handle_, usb_.endpoint_in, in_.buffer.data(), static_cast<int>(usb_.in_size),
                                 on_transfer_done, &in_.completed, timeout_ms_);
  libusb_fill_interrupt_transfer(out_.transfer, handle_, usb_.endpoint_out, out_.buffer.data(), static_cast<int>(usb_.out_size),
                                 on_transfer_done, &out_.completed, timeout_ms_);
  return Result<void>::success();
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

Result<void> UsbArm::send_report(std::uint32_t enable_word, bool reset, const char* what) {
  enable_word_ = enable_word;
  encode_out(nullptr, enable_word, reset);
  IoStatus s = transfer(out_, usb_.endpoint_out);
  if (s == IoStatus::kOk && out_.actual_length != static_cast<int>(usb_.out_size)) s = IoStatus::kProtocolError;
  if (s == IoStatus::kOk) return Result<void>::success();
  return Result<void>::failure(s == IoStatus::kDisconnected ? ErrorCode::kNotFound : ErrorCode::kSystem,
                          name() + ": sending " + what + " (zero currents) to " + location(bus_number_, address_) + " failed: " +
                              to_string(s) + (s == IoStatus::kTimeout ? " after " + std::to_string(timeout_ms_) + " ms" : std::string()) +
                              (detail_[0] != '\0' ? std::string(" (") + detail_ + ")" : std::string()));
}

Result<void> UsbArm::read_report(const std::string& what) {
  IoStatus s = transfer(in_, usb_.endpoint_in);
  if (s == IoStatus::kOk && in_.actual_length != static_cast<int>(usb_.in_size)) s = IoStatus::kProtocolError;
  if (s == IoStatus::kOk && usb_.in_report_id && in_.buffer[0] != *usb_.in_report_id) s = IoStatus::kProtocolError;
  if (s == IoStatus::kOk) return Result<void>::success();
  return Result<void>::failure(s == IoStatus::kDisconnected ? ErrorCode::kNotFound : ErrorCode::kSystem,
                          name() + ": " + what + ": no well-formed IN report from " + location(bus_number_, address_) + " (" + to_string(s) + ")");
}

std::uint32_t UsbArm::status_in_report() const noexcept {
  return usb_.status ? read_bits(in_.buffer.data() + usb_.status->offset, usb_.status->type, usb_.status->byte_order) : 0u;
}

Result<void> UsbArm::enable_drives(const std::string& step, bool always_reset) {
  const arm::StatusBits& bits = usb_.status_bits;
  const auto faulted = [&](std::uint32_t w) { return bits.fault.active(w) || bits.comm_lost.active(w) || bits.estop.active(w); };
  Result<void> o = usb_.status ? read_report(step + ": reading the status") : Result<void>::success();
  if (!o.ok()) return o;
  if (usb_.fault_reset && (always_reset || faulted(status_in_report()))) {
    o = send_report(usb_.enable_off, true, "the fault-reset report");
    if (!o.ok()) return o;
  }
  o = send_report(usb_.enable_on, false, "the enable report");
  drives_on_ = o.ok();
  // The firmware may take a report or two to leave its fault or enable: give it kSettleNs.
  const std::int64_t give_up = monotonic_ns() + kSettleNs;
  char text[112];
  while (o.ok() && usb_.status) {
    o = read_report(step + ": reading the status");
    if (!o.ok()) break;
    const std::uint32_t word = status_in_report();
    if (describe_status(bits, word, true, text, sizeof text) == 0) break;
    if (monotonic_ns() >= give_up) {
      o = Result<void>::failure(ErrorCode::kNotReady, name() + ": " + step + (faulted(word) ? ": the device still reports a fault after the fault reset ("
                                                                                        : ": the device is not ready after the enable (") +
                                                     text + ")");
      break;
    }
  }
  if (!o.ok()) {
    drives_on_ = false;
    (void)send_report(usb_.enable_off, false, "the disable report");  // best effort: stay disabled
  }
  return o;
}

// --------------------------------------------------------------------------------------------
// Lifecycle hooks

Result<void> UsbArm::on_configure() {
  Result<void> o = reopen();  // a fresh context each attempt: a retry sees a newly plugged arm
  if (!o.ok()) return o;

  // The arm must answer: wait a little for one well-formed IN report.
  const std::int64_t until = monotonic_ns() + std::max(kFirstReportWindowNs, 10 * timeout_ns_);
  IoStatus s = IoStatus::kTimeout;
  do {
    s = transfer(in_, usb_.endpoint_in);
    if (s == IoStatus::kOk && in_.actual_length != static_cast<int>(usb_.in_size)) {
      close_device();
      return Result<void>::failure(ErrorCode::kMismatch, name() + ": the first IN report from " + location(bus_number_, address_) + " has " +
                                                        std::to_string(in_.actual_length) + " bytes, expected " +
                                                        std::to_string(usb_.in_size) + " (bus.usb.in_report.size)");
    }
    if (s == IoStatus::kOk && usb_.in_report_id && in_.buffer[0] != *usb_.in_report_id) {
      close_device();
      return Result<void>::failure(ErrorCode::kMismatch, name() + ": the first IN report from " + location(bus_number_, address_) +
                                                        " has report id " + std::to_string(in_.buffer[0]) + ", expected " +
                                                        std::to_string(*usb_.in_report_id) + " (bus.usb.in_report.report_id)");
    }
  } while (s == IoStatus::kTimeout && monotonic_ns() < until);
  if (s != IoStatus::kOk) {
    close_device();
    return Result<void>::failure(ErrorCode::kNotReady, name() + ": the arm at " + location(bus_number_, address_) +
                                                      " does not answer: no IN report on " + hex2(usb_.endpoint_in) + " (" + to_string(s) + ")");
  }
  return Result<void>::success();
}

Result<void> UsbArm::reopen() {
  // A fresh context: its scan finds the arm wherever it came back, even if a hotplug event was
  // missed.
  close_device();
  if (ctx_ != nullptr) libusb_exit(ctx_);
  ctx_ = nullptr;
  const int r = libusb_init(&ctx_);
  if (r != 0) {
    ctx_ = nullptr;
    return Result<void>::failure(ErrorCode::kSystem, name() + ": libusb_init failed: " + libusb_strerror(r));
  }
  return open_and_claim();
}

Result<void> UsbArm::on_activate() {
  reset_estimator();
  if (handle_ == nullptr || lost_) {
    Result<void> o = reopen();
    if (!o.ok()) return o;
  } else if (!claimed_) {
    const int r = libusb_claim_interface(handle_, usb_.interface_number);
    if (r != 0)
      return Result<void>::failure(ErrorCode::kInUse, name() + ": cannot claim interface " + std::to_string(usb_.interface_number) +
                                                     " again: " + libusb_strerror(r));
    claimed_ = true;
  }
  return enable_drives("activate", false);
}

Result<void> UsbArm::on_deactivate() {
  drives_on_ = false;
  if (handle_ == nullptr || lost_) {
    enable_word_ = usb_.enable_off;
    return Result<void>::success();  // nothing left to drive
  }
  // The interface stays claimed: read() works while inactive (probing, monitoring); it is
  // released when the UsbArm goes.
  return claimed_ ? send_report(usb_.enable_off, false, "the disable report") : Result<void>::success();
}

Result<void> UsbArm::on_rearm() {
  reset_estimator();
  if (handle_ != nullptr && !lost_ && claimed_) {
    Result<void> o = enable_drives("rearm", true);
    // Only a bus error (gone, I/O) is worth a reopen; a timeout or a bad reply is reported.
    if (o.ok() || o.error().code != ErrorCode::kNotFound) return o;
  }
  Result<void> o = reopen();
  if (!o.ok()) return o;
  return enable_drives("rearm", true);
}

Result<void> UsbArm::on_reconnect() {
  // Open the arm wherever it is now (it may have come back at a new address) and keep its drives
  // off: zero currents, enable `off`, until rearm().
  drives_on_ = false;
  reset_estimator();
  Result<void> o = reopen();
  if (o.ok()) o = send_report(usb_.enable_off, false, "the disable report");
  if (o.ok()) o = read_report("reconnect");
  if (!o.ok()) lost_ = true;  // the next reconnect opens it again
  return o;
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
  detail_ = "";
  if (slot.in_flight && finish_in_flight(slot) != IoStatus::kOk) {
    detail_ = lost_ ? "the device is gone" : "the previous transfer has not come back yet";
    return lost_ ? IoStatus::kDisconnected : IoStatus::kTimeout;
  }
  slot.completed = 0;
  slot.actual_length = 0;
  slot.transfer->timeout = timeout_ms_;  // set_timeout() may have changed it
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
      detail_ = lost_ ? "the device is gone" : "no reply, and the cancelled transfer did not come back";
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
    case LIBUSB_TRANSFER_CANCELLED: detail_ = "no reply within the transfer timeout"; return IoStatus::kTimeout;
    case LIBUSB_TRANSFER_NO_DEVICE: lost_ = true; detail_ = "the device is gone (unplugged?)"; return IoStatus::kDisconnected;
    case LIBUSB_TRANSFER_ERROR: detail_ = "transfer error (I/O on the bus)"; return IoStatus::kDisconnected;
    case LIBUSB_TRANSFER_OVERFLOW: detail_ = "the device sent more than the report size"; return IoStatus::kProtocolError;
    case LIBUSB_TRANSFER_STALL: {
      ++stats_.clear_halts;
      const int r = libusb_clear_halt(handle_, endpoint);
      if (r == 0) {
        detail_ = "the endpoint stalled (halt cleared)";
        return IoStatus::kProtocolError;
      }
      if (r == LIBUSB_ERROR_NO_DEVICE) lost_ = true;
      detail_ = "the endpoint stalled and its halt cannot be cleared";
      return IoStatus::kDisconnected;
    }
    default: detail_ = "unexpected transfer status"; return IoStatus::kProtocolError;
  }
}

IoStatus UsbArm::status_from_error(int e) noexcept {
  detail_ = libusb_strerror(e);  // a static string
  switch (e) {
    case LIBUSB_ERROR_TIMEOUT:
    case LIBUSB_ERROR_BUSY: return IoStatus::kTimeout;
    case LIBUSB_ERROR_NO_DEVICE:
      lost_ = true;
      detail_ = "the device is gone (unplugged?)";
      return IoStatus::kDisconnected;
    case LIBUSB_ERROR_IO:
    case LIBUSB_ERROR_PIPE: return IoStatus::kDisconnected;
    default: return IoStatus::kProtocolError;
  }
}

IoStatus UsbArm::io_error(IoStatus s, unsigned char endpoint, const char* what) noexcept {
  char text[112];
  std::snprintf(text, sizeof text, "bus %03u address %03u, %s 0x%02x: %s", static_cast<unsigned>(bus_number_), static_cast<unsigned>(address_),
                (endpoint & LIBUSB_ENDPOINT_IN) != 0 ? "IN" : "OUT", static_cast<unsigned>(endpoint), what);
  note_error(s, -1, endpoint, text);
  return s;
}

void UsbArm::encode_out(const JointCommand* cmd, std::uint32_t enable_word, bool reset) noexcept {
  const arm::ReportField& f = usb_.setpoint;
  const int size = arm::field_size(f.type);
  const bool torque = usb_.setpoint_kind == arm::SetpointKind::kTorque;
  std::uint8_t* b = out_.buffer.data();
  for (int j = 0; j < n_; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const arm::ActuatorConfig& act = config_.actuators[uj];
    double tau = cmd != nullptr && j < cmd->n ? cmd->tau[uj] : 0.0;
    if (!std::isfinite(tau)) tau = 0.0;
    double amps = arm::motor_current_for_joint_torque(config_.joints[uj], act, tau);
    if (!std::isfinite(amps)) amps = 0;
    amps = std::clamp(amps, -act.peak_current, act.peak_current);
    const double physical = torque ? amps * act.torque_constant : amps;
    (void)write_value(b + f.offset + static_cast<std::size_t>(j * size), f.type, f.byte_order, (physical - f.bias) / f.scale);
  }
  // A fault reset shares the enable field, or has its own (released to 0 in every other report).
  const bool shared = usb_.enable && usb_.fault_reset && usb_.enable->offset == usb_.fault_reset->offset;
  if (usb_.enable) write_bits(b + usb_.enable->offset, usb_.enable->type, usb_.enable->byte_order, reset && shared ? usb_.fault_reset_value : enable_word);
  if (usb_.fault_reset && !shared)
    write_bits(b + usb_.fault_reset->offset, usb_.fault_reset->type, usb_.fault_reset->byte_order, reset ? usb_.fault_reset_value : 0u);
  if (usb_.heartbeat) {
    // Counts up in every OUT report and wraps within the field: the device's keep-alive.
    ++heartbeat_;
    const int bits = 8 * arm::field_size(usb_.heartbeat->type);
    if (bits < 32) heartbeat_ &= (1u << bits) - 1u;
    write_bits(b + usb_.heartbeat->offset, usb_.heartbeat->type, usb_.heartbeat->byte_order, heartbeat_);
  }
}

IoStatus UsbArm::on_read(JointState& out) noexcept {
  if (handle_ == nullptr || lost_ || !claimed_) return io_error(IoStatus::kDisconnected, usb_.endpoint_in, "the device is not open (it went away)");
  const IoStatus s = transfer(in_, usb_.endpoint_in);
  if (s != IoStatus::kOk) return io_error(s, usb_.endpoint_in, detail_);
  if (in_.actual_length != static_cast<int>(usb_.in_size)) {
    char what[64];
    std::snprintf(what, sizeof what, "short report: %d of %u bytes", in_.actual_length, static_cast<unsigned>(usb_.in_size));
    return io_error(IoStatus::kProtocolError, usb_.endpoint_in, what);
  }
  const std::uint8_t* b = in_.buffer.data();
  if (usb_.in_report_id && b[0] != *usb_.in_report_id) {
    char what[64];
    std::snprintf(what, sizeof what, "report id %u, expected %u", static_cast<unsigned>(b[0]), static_cast<unsigned>(*usb_.in_report_id));
    return io_error(IoStatus::kProtocolError, usb_.endpoint_in, what);
  }

  // The report is well formed: decode it and update the estimator.
  const arm::ReportField& ef = usb_.encoder_counts;
  const int size = arm::field_size(ef.type);
  const std::int64_t t = in_.done_ns;
  out.n = n_;
  for (int j = 0; j < n_; ++j) {
    const auto uj = static_cast<std::size_t>(j);
    const std::uint8_t* p = b + ef.offset + static_cast<std::size_t>(j * size);
    double raw = 0;
    if (ef.type == arm::FieldType::kF32) {
      const float f = std::bit_cast<float>(read_bits(p, ef.type, ef.byte_order));
      raw = std::isfinite(f) ? f : 0.0;
    } else {
      // A narrow counter that wraps is unwrapped (the first report after a reset is taken as is).
      const std::int64_t r = read_field(p, ef.type, ef.byte_order);
      raw_[uj] = have_sample_ ? raw_[uj] + wrapped_delta(r, last_raw_[uj], ef.type) : r;
      last_raw_[uj] = r;
      raw = static_cast<double>(raw_[uj]);
    }
    const double c = std::clamp(ef.scale * raw + ef.bias, -9.0e15, 9.0e15);
    const auto whole = static_cast<std::int64_t>(std::llround(c));
    const auto& jc = config_.joints[uj];
    // Exact for whole counts; a scaled encoder keeps its fraction of a count.
    out.q[uj] = arm::joint_position_from_counts(jc, whole) +
                (c - static_cast<double>(whole)) * (arm::joint_position_from_counts(jc, 1) - arm::joint_position_from_counts(jc, 0));
    out.counts[uj] = whole;
  }
  velocity_.update(n_, out.q, t, out.qd);
  have_sample_ = true;

  std::uint32_t word = 0;
  if (usb_.buttons) word = read_bits(b + usb_.buttons->offset, usb_.buttons->type, usb_.buttons->byte_order);
  out.buttons = pressed_buttons(config_.buttons, word);
  out.status = status_in_report();
  if (usb_.status && drives_on_) {
    char text[112];
    if (describe_status(usb_.status_bits, out.status, true, text, sizeof text) > 0) {
      note_error(IoStatus::kDeviceFault, -1, out.status, text);
      return IoStatus::kDeviceFault;
    }
  }
  return IoStatus::kOk;
}

IoStatus UsbArm::on_write(const JointCommand& cmd) noexcept {
  if (handle_ == nullptr || lost_ || !claimed_) return io_error(IoStatus::kDisconnected, usb_.endpoint_out, "the device is not open (it went away)");
  encode_out(&cmd, enable_word_, false);
  const IoStatus s = transfer(out_, usb_.endpoint_out);
  if (s != IoStatus::kOk) return io_error(s, usb_.endpoint_out, detail_);
  if (out_.actual_length != static_cast<int>(usb_.out_size)) {
    char what[64];
    std::snprintf(what, sizeof what, "the device took %d of %u bytes", out_.actual_length, static_cast<unsigned>(usb_.out_size));
    return io_error(IoStatus::kProtocolError, usb_.endpoint_out, what);
  }
  return IoStatus::kOk;
}

}  // namespace lancet::device
