#include "device/ftdi.hpp"

#include <libusb.h>
#include <time.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <vector>

namespace lancet::device::ftdi {

namespace {

constexpr double kClockEighths = 24'000'000.0;  // the 3 MHz divisor clock, in eighths of a count
constexpr std::int64_t kCancelWaitNs = 100'000'000;

// The chip's code for each fraction k/8 of the divisor (FT232BM/R; AN232B-05) and back.
constexpr std::array<std::uint32_t, 8> kFractionCode = {0, 3, 2, 4, 1, 5, 6, 7};
constexpr std::array<std::uint32_t, 8> kCodeFraction = {0, 4, 2, 1, 3, 5, 6, 7};

std::int64_t now_ns() noexcept {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

std::string hex4(unsigned v) {
  char b[8];
  std::snprintf(b, sizeof b, "%04x", v & 0xFFFFu);
  return b;
}

std::string where(libusb_device* d) {
  char b[40];
  std::snprintf(b, sizeof b, "bus %03u address %03u", static_cast<unsigned>(libusb_get_bus_number(d)),
                static_cast<unsigned>(libusb_get_device_address(d)));
  return b;
}

IoStatus status_of(int libusb_error) noexcept {
  switch (libusb_error) {
    case LIBUSB_ERROR_TIMEOUT: return IoStatus::kTimeout;
    case LIBUSB_ERROR_NO_DEVICE:
    case LIBUSB_ERROR_IO:
    case LIBUSB_ERROR_NOT_FOUND: return IoStatus::kDisconnected;
    default: return IoStatus::kProtocolError;
  }
}

}  // namespace

void in_done_trampoline(libusb_transfer* t) { static_cast<Port*>(t->user_data)->on_in_done(); }
void out_done_trampoline(libusb_transfer* t) { static_cast<Port*>(t->user_data)->on_out_done(); }

namespace {
extern "C" void LIBUSB_CALL in_done_c(libusb_transfer* t) { in_done_trampoline(t); }
extern "C" void LIBUSB_CALL out_done_c(libusb_transfer* t) { out_done_trampoline(t); }
}  // namespace

// --------------------------------------------------------------------------------------------
// Baud rates and packets

std::optional<BaudSetting> baud_setting(double baud) noexcept {
  if (!std::isfinite(baud) || baud <= 0) return std::nullopt;
  // Candidates: the two special divisors, and the eighths just below and above the exact one.
  struct Candidate {
    std::uint32_t eighths;  // 8 and 12 are the specials (3 and 2 Mbaud)
    double rate;
  };
  std::array<Candidate, 4> c{};
  std::size_t n = 0;
  c[n++] = {8, 3'000'000.0};
  c[n++] = {12, 2'000'000.0};
  const double exact = kClockEighths / baud;
  for (const double e : {std::floor(exact), std::ceil(exact)}) {
    const double clamped = std::clamp(e, 16.0, static_cast<double>(0x3FFF * 8 + 7));
    c[n++] = {static_cast<std::uint32_t>(clamped), kClockEighths / clamped};
  }
  const Candidate* best = &c[0];
  for (std::size_t i = 1; i < n; ++i)
    if (std::abs(c[i].rate - baud) < std::abs(best->rate - baud)) best = &c[i];
  if (std::abs(best->rate - baud) > 0.03 * baud) return std::nullopt;
  BaudSetting s;
  s.actual = best->rate;
  if (best->eighths == 8) return s;  // value 0: 3 Mbaud
  if (best->eighths == 12) {
    s.value = 1;  // 2 Mbaud
    return s;
  }
  const std::uint32_t encoded = (best->eighths >> 3) | (kFractionCode[best->eighths & 7] << 14);
  s.value = static_cast<std::uint16_t>(encoded & 0xFFFF);
  s.index = static_cast<std::uint16_t>(encoded >> 16);
  return s;
}

double baud_of(std::uint16_t value, std::uint16_t index) noexcept {
  const std::uint32_t encoded = value | ((static_cast<std::uint32_t>(index) & 1u) << 16);
  const std::uint32_t whole = encoded & 0x3FFF, code = encoded >> 14;
  if (code == 0 && whole == 0) return 3'000'000.0;
  if (code == 0 && whole == 1) return 2'000'000.0;
  return kClockEighths / static_cast<double>(whole * 8 + kCodeFraction[code & 7]);
}

std::size_t strip_modem_status(std::span<const std::uint8_t> in, std::size_t packet_size, std::span<std::uint8_t> out) noexcept {
  if (packet_size <= static_cast<std::size_t>(kModemStatusBytes)) return 0;
  std::size_t written = 0;
  for (std::size_t at = 0; at < in.size(); at += packet_size) {
    const std::size_t end = std::min(in.size(), at + packet_size);
    if (end <= at + kModemStatusBytes) continue;
    const std::size_t n = std::min(end - at - kModemStatusBytes, out.size() - written);
    std::memcpy(out.data() + written, in.data() + at + kModemStatusBytes, n);
    written += n;
  }
  return written;
}

// --------------------------------------------------------------------------------------------
// Opening

Result<std::unique_ptr<Port>> Port::open(const PortId& id) {
  std::unique_ptr<Port> p(new Port());
  p->id_ = id;
  const std::string want = id.what + " (" + hex4(id.vid) + ":" + hex4(id.pid) + ")";
  if (const int r = libusb_init(&p->ctx_); r != 0) {
    p->ctx_ = nullptr;
    return Error{ErrorCode::kSystem, "libusb cannot start (" + std::string(libusb_error_name(r)) + "): no USB support here"};
  }
  libusb_device** list = nullptr;
  const ssize_t count = libusb_get_device_list(p->ctx_, &list);
  std::vector<libusb_device*> matches;
  std::string same_vendor;
  for (ssize_t i = 0; i < count; ++i) {
    libusb_device_descriptor d{};
    if (libusb_get_device_descriptor(list[i], &d) != 0) continue;
    if (d.idVendor == id.vid && d.idProduct == id.pid) matches.push_back(list[i]);
    else if (d.idVendor == id.vid) same_vendor += (same_vendor.empty() ? "" : ", ") + hex4(d.idVendor) + ":" + hex4(d.idProduct) + " at " + where(list[i]);
  }
  if (matches.size() <= static_cast<std::size_t>(id.index)) {
    std::string msg;
    if (matches.empty()) {
      msg = "no " + want + " on the USB bus";
      msg += same_vendor.empty() ? " (" + std::to_string(std::max<ssize_t>(count, 0)) + " USB devices seen, none of vendor " + hex4(id.vid) + ")"
                                 : ": a device of the same vendor has another product id (" + same_vendor +
                                       "); if it is the device, set its pid in the config";
    } else {
      msg = "index " + std::to_string(id.index) + " asks for device " + std::to_string(id.index + 1) + " of " + want + ", but " +
            std::to_string(matches.size()) + (matches.size() == 1 ? " is" : " are") + " plugged in";
    }
    if (list != nullptr) libusb_free_device_list(list, 1);
    return Error{ErrorCode::kNotFound, msg};
  }
  libusb_device* dev = matches[static_cast<std::size_t>(id.index)];
  p->location_ = where(dev);
  // Both bulk endpoints on the interface, and the IN packet size.
  libusb_config_descriptor* cd = nullptr;
  bool in_ok = false, out_ok = false;
  std::string seen;
  if (libusb_get_active_config_descriptor(dev, &cd) == 0 && cd != nullptr) {
    for (int i = 0; i < cd->bNumInterfaces; ++i) {
      const libusb_interface& itf = cd->interface[i];
      for (int a = 0; a < itf.num_altsetting; ++a) {
        const libusb_interface_descriptor& alt = itf.altsetting[a];
        if (alt.bInterfaceNumber != id.interface_number) continue;
        for (int e = 0; e < alt.bNumEndpoints; ++e) {
          const libusb_endpoint_descriptor& ep = alt.endpoint[e];
          const bool bulk = (ep.bmAttributes & LIBUSB_TRANSFER_TYPE_MASK) == LIBUSB_ENDPOINT_TRANSFER_TYPE_BULK;
          char b[48];
          std::snprintf(b, sizeof b, "%s0x%02x %s", seen.empty() ? "" : ", ", ep.bEndpointAddress, bulk ? "bulk" : "not bulk");
          seen += b;
          if (bulk && ep.bEndpointAddress == id.endpoint_in) {
            in_ok = true;
            p->packet_size_ = std::clamp<std::size_t>(ep.wMaxPacketSize, 8, p->in_buf_.size());
          }
          if (bulk && ep.bEndpointAddress == id.endpoint_out) out_ok = true;
        }
      }
    }
    libusb_free_config_descriptor(cd);
  }
  const int opened = (in_ok && out_ok) ? libusb_open(dev, &p->handle_) : 0;
  libusb_free_device_list(list, 1);
  if (!in_ok || !out_ok) {
    char b[96];
    std::snprintf(b, sizeof b, "no bulk endpoints 0x%02x IN and 0x%02x OUT on interface %d", id.endpoint_in, id.endpoint_out,
                  id.interface_number);
    return Error{ErrorCode::kInvalid, want + " at " + p->location_ + ": " + b + " (found: " + (seen.empty() ? "none" : seen) + ")"};
  }
  if (opened != 0) {
    p->handle_ = nullptr;
    return Error{ErrorCode::kSystem, want + " at " + p->location_ + ": cannot open (" + libusb_error_name(opened) +
                                     "; LIBUSB_ERROR_ACCESS: add a udev rule for " + hex4(id.vid) + ":" + hex4(id.pid) +
                                     ", see hw_configs/README.md)"};
  }
  if (libusb_kernel_driver_active(p->handle_, id.interface_number) == 1) {
    if (const int r = libusb_detach_kernel_driver(p->handle_, id.interface_number); r != 0)
      return Error{ErrorCode::kSystem, want + " at " + p->location_ + ": the kernel's driver (ftdi_sio) holds it and cannot be detached (" +
                                       libusb_error_name(r) + ")"};
    p->detached_driver_ = true;
  }
  if (const int r = libusb_claim_interface(p->handle_, id.interface_number); r != 0)
    return Error{ErrorCode::kSystem, want + " at " + p->location_ + ": cannot claim interface " + std::to_string(id.interface_number) + " (" +
                                     libusb_error_name(r) + ")"};
  p->claimed_ = true;
  p->in_ = libusb_alloc_transfer(0);
  p->out_ = libusb_alloc_transfer(0);
  if (p->in_ == nullptr || p->out_ == nullptr) return Error{ErrorCode::kSystem, "libusb cannot allocate a transfer"};
  return p;
}

Port::~Port() {
  stop_streaming();
  if (out_in_flight_ && handle_ != nullptr) {
    libusb_cancel_transfer(out_);
    (void)pump(now_ns() + kCancelWaitNs, [this] { return !out_in_flight_; });
  }
  // A transfer libusb still holds is leaked rather than freed under it (does not happen on a live bus).
  if (in_ != nullptr && !in_flight_) libusb_free_transfer(in_);
  if (out_ != nullptr && !out_in_flight_) libusb_free_transfer(out_);
  if (handle_ != nullptr) {
    if (claimed_) (void)libusb_release_interface(handle_, id_.interface_number);
    if (detached_driver_ && !lost_) (void)libusb_attach_kernel_driver(handle_, id_.interface_number);
    libusb_close(handle_);
  }
  if (ctx_ != nullptr) libusb_exit(ctx_);
}

// --------------------------------------------------------------------------------------------
// Setup requests

Result<void> Port::control(std::uint8_t request, std::uint16_t value, const char* what) {
  return control_indexed(request, value, 0, what);
}

Result<void> Port::control_indexed(std::uint8_t request, std::uint16_t value, std::uint16_t index, const char* what) {
  const int r = libusb_control_transfer(handle_, kVendorOut, request, value, index, nullptr, 0, 1000);
  if (r < 0) {
    if (r == LIBUSB_ERROR_NO_DEVICE) lost_ = true;
    char b[64];
    std::snprintf(b, sizeof b, " (request 0x%02x, value 0x%04x)", request, value);
    return Error{r == LIBUSB_ERROR_NO_DEVICE ? ErrorCode::kSystem : ErrorCode::kMismatch,
                 id_.what + " at " + location_ + ": the chip refused " + what + b + ": " + libusb_error_name(r)};
  }
  return {};
}

Result<void> Port::purge() {
  if (auto r = control(kReset, kPurgeRx, "purging its receive buffer"); !r.ok()) return r;
  if (auto r = control(kReset, kPurgeTx, "purging its transmit buffer"); !r.ok()) return r;
  clear_rx();
  return {};
}

Result<void> Port::set_baud(double baud) {
  const auto s = baud_setting(baud);
  if (!s) return Error{ErrorCode::kInvalid, id_.what + ": " + std::to_string(baud) + " baud is not a rate the chip can run at"};
  return control_indexed(kBaudRate, s->value, static_cast<std::uint16_t>(s->index), "the baud rate");
}

Result<void> Port::set_latency_ms(int ms) {
  return control(kLatencyTimer, static_cast<std::uint16_t>(std::clamp(ms, 1, 255)), "the latency timer");
}

Result<void> Port::set_8n1_no_flow_control() {
  if (auto r = control(kDataFormat, k8N1, "8N1"); !r.ok()) return r;
  return control(kFlowControl, 0, "no flow control");
}

Result<void> Port::write_all(std::span<const std::uint8_t> data, double timeout_s, const char* what) {
  std::size_t done = 0;
  const auto ms = static_cast<unsigned>(std::max(1.0, std::ceil(timeout_s * 1e3)));
  while (done < data.size()) {
    int sent = 0;
    const int r = libusb_bulk_transfer(handle_, id_.endpoint_out, const_cast<std::uint8_t*>(data.data() + done),
                                       static_cast<int>(data.size() - done), &sent, ms);
    done += static_cast<std::size_t>(std::max(sent, 0));
    if (r != 0) {
      if (r == LIBUSB_ERROR_NO_DEVICE) lost_ = true;
      return Error{r == LIBUSB_ERROR_TIMEOUT ? ErrorCode::kNotReady : ErrorCode::kSystem,
                   id_.what + " at " + location_ + ": writing " + what + " failed after " + std::to_string(done) + " of " +
                       std::to_string(data.size()) + " bytes: " + libusb_error_name(r)};
    }
  }
  return {};
}

Result<void> Port::read_exact(std::span<std::uint8_t> out, double timeout_s, const char* what) {
  if (!streaming_) return Error{ErrorCode::kInvalid, id_.what + ": reading " + what + " needs start_streaming() first"};
  const std::int64_t deadline = now_ns() + static_cast<std::int64_t>(timeout_s * 1e9);
  std::size_t got = 0;
  for (;;) {
    const std::size_t n = std::min(rx_size_, out.size() - got);
    std::memcpy(out.data() + got, rx_.data(), n);
    take(n);
    got += n;
    if (got == out.size()) return {};
    const IoStatus s = wait_for(1, deadline);
    if (s == IoStatus::kDisconnected) return Error{ErrorCode::kSystem, id_.what + " at " + location_ + ": gone while reading " + what};
    if (s != IoStatus::kOk) break;
  }
  return Error{ErrorCode::kNotReady, id_.what + " at " + location_ + ": " + what + ": " + std::to_string(got) + " of " +
                                        std::to_string(out.size()) + " bytes came within " + std::to_string(static_cast<int>(timeout_s * 1e3)) +
                                        " ms"};
}

// --------------------------------------------------------------------------------------------
// The exchange

Result<void> Port::start_streaming() {
  if (streaming_) return {};
  libusb_fill_bulk_transfer(in_, handle_, id_.endpoint_in, in_buf_.data(), static_cast<int>(packet_size_), &in_done_c, this, 0);
  libusb_fill_bulk_transfer(out_, handle_, id_.endpoint_out, out_buf_.data(), 0, &out_done_c, this, 0);
  if (const int r = libusb_submit_transfer(in_); r != 0) {
    if (r == LIBUSB_ERROR_NO_DEVICE) lost_ = true;
    return Error{ErrorCode::kSystem, id_.what + " at " + location_ + ": cannot start reading: " + libusb_error_name(r)};
  }
  in_flight_ = true;
  streaming_ = true;
  return {};
}

void Port::stop_streaming() noexcept {
  streaming_ = false;
  if (!in_flight_ || handle_ == nullptr) return;
  libusb_cancel_transfer(in_);
  (void)pump(now_ns() + kCancelWaitNs, [this] { return !in_flight_; });
}

void Port::on_in_done() noexcept {
  in_flight_ = false;
  const int status = in_->status;
  if (status == LIBUSB_TRANSFER_COMPLETED) {
    ++stats_.in_packets;
    std::array<std::uint8_t, 512> data{};
    const std::size_t n = strip_modem_status({in_buf_.data(), static_cast<std::size_t>(in_->actual_length)}, packet_size_, data);
    stats_.in_bytes += n;
    if (rx_size_ + n > rx_.size()) {  // the reader fell behind: keep the newest bytes
      const std::size_t drop = rx_size_ + n - rx_.size();
      stats_.rx_overflow_bytes += drop;
      take(std::min(drop, rx_size_));
    }
    const std::size_t keep = std::min(n, rx_.size() - rx_size_);
    std::memcpy(rx_.data() + rx_size_, data.data() + (n - keep), keep);
    rx_size_ += keep;
  } else if (status != LIBUSB_TRANSFER_CANCELLED) {
    ++stats_.in_errors;
    if (status == LIBUSB_TRANSFER_NO_DEVICE) {
      lost_ = true;
      detail_ = "the device is gone (IN transfer: no device)";
    } else {
      detail_ = status == LIBUSB_TRANSFER_OVERFLOW ? "IN transfer overflow" : status == LIBUSB_TRANSFER_STALL ? "IN endpoint stalled" : "IN transfer failed";
    }
  }
  if (!streaming_ || lost_ || status == LIBUSB_TRANSFER_CANCELLED) return;
  const int r = libusb_submit_transfer(in_);
  if (r == 0) {
    in_flight_ = true;
  } else {
    lost_ = r == LIBUSB_ERROR_NO_DEVICE || r == LIBUSB_ERROR_IO;
    streaming_ = false;
    detail_ = lost_ ? "the device is gone (resubmitting the IN transfer)" : "cannot resubmit the IN transfer";
  }
}

void Port::on_out_done() noexcept {
  out_in_flight_ = false;
  const int status = out_->status;
  if (status == LIBUSB_TRANSFER_NO_DEVICE) {
    lost_ = true;
    detail_ = "the device is gone (OUT transfer: no device)";
  } else if (status != LIBUSB_TRANSFER_COMPLETED && status != LIBUSB_TRANSFER_CANCELLED) {
    detail_ = "OUT transfer failed";
  }
}

template <class Done>
bool Port::pump(std::int64_t deadline_ns, Done done) noexcept {
  while (!done()) {
    const std::int64_t left = deadline_ns - now_ns();
    if (left <= 0) return true;
    timeval tv{0, static_cast<suseconds_t>(std::min<std::int64_t>(left / 1000 + 1, 100'000))};
    if (libusb_handle_events_timeout_completed(ctx_, &tv, nullptr) != 0) return false;
  }
  return true;
}

IoStatus Port::submit_write(std::span<const std::uint8_t> data, std::int64_t deadline_ns) noexcept {
  if (lost_) return IoStatus::kDisconnected;
  if (data.size() > out_buf_.size()) return IoStatus::kProtocolError;
  (void)pump(deadline_ns, [this] { return !out_in_flight_; });
  if (out_in_flight_) {
    detail_ = "the previous write has not gone out";
    return IoStatus::kTimeout;
  }
  if (lost_) return IoStatus::kDisconnected;
  std::memcpy(out_buf_.data(), data.data(), data.size());
  out_->length = static_cast<int>(data.size());
  const int r = libusb_submit_transfer(out_);
  if (r != 0) {
    lost_ = r == LIBUSB_ERROR_NO_DEVICE;
    detail_ = lost_ ? "the device is gone (submitting a write)" : "cannot submit a write";
    return status_of(r);
  }
  out_in_flight_ = true;
  ++stats_.writes;
  return IoStatus::kOk;
}

IoStatus Port::wait_for(std::size_t bytes, std::int64_t deadline_ns) noexcept {
  const bool events_ok = pump(deadline_ns, [&] { return rx_size_ >= bytes || lost_ || !streaming_; });
  if (rx_size_ >= bytes) return IoStatus::kOk;
  if (lost_) return IoStatus::kDisconnected;
  if (!streaming_ || !events_ok) return IoStatus::kProtocolError;
  return IoStatus::kTimeout;
}

void Port::take(std::size_t n) noexcept {
  n = std::min(n, rx_size_);
  std::memmove(rx_.data(), rx_.data() + n, rx_size_ - n);
  rx_size_ -= n;
}

}  // namespace lancet::device::ftdi
