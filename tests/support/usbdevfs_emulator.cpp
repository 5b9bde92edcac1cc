#include "usbdevfs_emulator.hpp"

#include <errno.h>
#include <linux/usbdevice_fs.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>

#include <umockdev.h>

#include <algorithm>
#include <cstddef>
#include <utility>

namespace lancet::test {
namespace {

usbdevfs_urb* urb_of(UMockdevIoctlData* d) { return reinterpret_cast<usbdevfs_urb*>(d->data); }

void complete(UMockdevIoctlClient* c, long ret, int err) { umockdev_ioctl_client_complete(c, ret, err); }

// The client's memory could not be read (the process died with the ioctl in flight, as a killed
// lancet-rt does): EFAULT, and nothing of it is kept.
bool client_gone(UMockdevIoctlClient* c) {
  complete(c, -1, EFAULT);
  return true;
}

// A programmer error in a hook (or its caller): say where and stop, in every build.
[[noreturn]] void misuse(const char* what) {
  fprintf(stderr, "UsbdevfsDevice: %s\n", what);
  abort();
}

}  // namespace

UsbdevfsDevice::UsbdevfsDevice(UsbdevfsInterface interface) : interface_(std::move(interface)) {}

UsbdevfsDevice::~UsbdevfsDevice() {
  for (auto& u : pending_) g_object_unref(u.data);
  for (auto& u : done_) g_object_unref(u.data);
}

void UsbdevfsDevice::plugged_at(const std::string& devnode) {
  auto lk = lock();
  live_ = devnode;
  unplugged_ = false;
  state_.claimed = false;
  state_.driver_bound = !interface_.kernel_driver.empty();  // the kernel binds a freshly enumerated device
}

void UsbdevfsDevice::unplug() {
  auto lk = lock();
  unplugged_ = true;
  for (auto& u : pending_) {
    urb_of(u.data)->status = -ENODEV;
    done_.push_back(u);
  }
  pending_.clear();
}

void UsbdevfsDevice::vanish_on_next_in() {
  auto lk = lock();
  vanish_next_in_ = true;
}

void UsbdevfsDevice::withhold_in(bool on) {
  auto lk = lock();
  withhold_ = on;
}

void UsbdevfsDevice::complete_pending_in() {
  auto lk = lock();
  if (withhold_ || completing_) return;  // a call from inside on_in(): the outer loop goes on
  completing_ = true;
  std::vector<std::uint8_t> starved;  // endpoints whose oldest URB got nothing_yet()
  const auto waiting = [&](const Urb& u) {
    return std::find(starved.begin(), starved.end(), urb_of(u.data)->endpoint) == starved.end();
  };
  for (auto it = std::find_if(pending_.begin(), pending_.end(), waiting); it != pending_.end();
       it = std::find_if(pending_.begin(), pending_.end(), waiting)) {
    const Urb u = *it;
    const std::uint8_t ep = urb_of(u.data)->endpoint;
    const UrbReply r = on_in(ep, std::span<std::uint8_t>(u.buffer, u.length));
    // Found again: the hook may have failed or unplugged what pended meanwhile.
    const auto same = std::find_if(pending_.begin(), pending_.end(), [&](const Urb& p) { return p.data == u.data; });
    if (same == pending_.end()) continue;
    if (r.kind == UrbReply::Kind::kNothingYet) {
      starved.push_back(ep);
      continue;
    }
    pending_.erase(same);
    finish(u, r);
  }
  completing_ = false;
}

bool UsbdevfsDevice::fail_pending_in(int negative_errno) {
  auto lk = lock();
  if (pending_.empty()) return false;
  const Urb u = pending_.front();
  pending_.pop_front();
  finish(u, UrbReply::failed(negative_errno));
  return true;
}

UsbdevfsState UsbdevfsDevice::state() const {
  auto lk = lock();
  UsbdevfsState s = state_;
  s.pending_in = pending_.size();
  return s;
}

UrbReply UsbdevfsDevice::on_control(const ControlSetup&, std::span<std::uint8_t>) { return UrbReply::stall(); }

// ---------------------------------------------------------------------------------------------
// Dispatch

bool UsbdevfsDevice::handle_ioctl(UMockdevIoctlClient* client) {
  const auto request = static_cast<unsigned long>(umockdev_ioctl_client_get_request(client));
  UMockdevIoctlData* arg = umockdev_ioctl_client_get_arg(client);
  auto lk = lock();
  const bool live = !unplugged_ && live_ == umockdev_ioctl_client_get_devnode(client);

  // Reaping and discarding work on a dead node too: what was in flight comes back.
  if (request == USBDEVFS_REAPURB || request == USBDEVFS_REAPURBNDELAY) return reap(client, arg, live);
  if (request == USBDEVFS_DISCARDURB) return discard(client, arg, live);
  if (!live) {
    complete(client, -1, ENODEV);
    return true;
  }
  switch (request) {
    case USBDEVFS_GET_CAPABILITIES: {
      UMockdevIoctlData* d = umockdev_ioctl_data_resolve(arg, 0, sizeof(std::uint32_t), nullptr);
      if (d == nullptr) return client_gone(client);
      const std::uint32_t caps = USBDEVFS_CAP_ZERO_PACKET | USBDEVFS_CAP_BULK_CONTINUATION | USBDEVFS_CAP_NO_PACKET_SIZE_LIM |
                                 USBDEVFS_CAP_BULK_SCATTER_GATHER | USBDEVFS_CAP_REAP_AFTER_DISCONNECT;
      memcpy(d->data, &caps, sizeof caps);
      g_object_unref(d);
      complete(client, 0, 0);
      return true;
    }
    case USBDEVFS_GETDRIVER:
    case USBDEVFS_IOCTL:
    case USBDEVFS_CLAIMINTERFACE:
    case USBDEVFS_RELEASEINTERFACE: answer_driver_ioctl(client, request, arg); return true;
    case USBDEVFS_CLEAR_HALT:
    case USBDEVFS_RESETEP:
    case USBDEVFS_RESET:
    case USBDEVFS_SETINTERFACE:
    case USBDEVFS_SETCONFIGURATION: complete(client, 0, 0); return true;
    case USBDEVFS_SUBMITURB: submit(client, arg); return true;
    default: complete(client, -1, ENOTTY); return true;
  }
}

// The oldest done URB of this fd goes back to it (its own URB pointer); none: EAGAIN, or ENODEV
// once the device is gone.
bool UsbdevfsDevice::reap(UMockdevIoctlClient* client, UMockdevIoctlData* arg, bool live) {
  const auto it = std::find_if(done_.begin(), done_.end(), [&](const Urb& u) { return u.client == client; });
  if (it == done_.end()) {
    complete(client, -1, live ? EAGAIN : ENODEV);
    return true;
  }
  const Urb u = *it;
  done_.erase(it);
  UMockdevIoctlData* ptr = umockdev_ioctl_data_resolve(arg, 0, sizeof(void*), nullptr);
  if (ptr == nullptr) {
    g_object_unref(u.data);
    return client_gone(client);
  }
  umockdev_ioctl_data_set_ptr(ptr, 0, u.data);  // the client sees its own URB come back
  g_object_unref(ptr);
  g_object_unref(u.data);
  complete(client, 0, 0);
  return true;
}

// A pending URB of this fd (named by its address in the client) completes with -ENOENT.
bool UsbdevfsDevice::discard(UMockdevIoctlClient* client, UMockdevIoctlData* arg, bool live) {
  const auto addr = *reinterpret_cast<const gulong*>(arg->data);
  const auto it =
      std::find_if(pending_.begin(), pending_.end(), [&](const Urb& u) { return u.client == client && u.data->client_addr == addr; });
  if (it == pending_.end()) {
    complete(client, -1, live ? EINVAL : ENODEV);
    return true;
  }
  urb_of(it->data)->status = -ENOENT;
  done_.push_back(*it);
  pending_.erase(it);
  ++state_.discards;
  complete(client, 0, 0);
  return true;
}

// GETDRIVER, the kernel driver's DISCONNECT / CONNECT (USBDEVFS_IOCTL), CLAIM / RELEASEINTERFACE:
// the interface is claimable only with the kernel driver detached, as in Linux.
void UsbdevfsDevice::answer_driver_ioctl(UMockdevIoctlClient* client, unsigned long request, UMockdevIoctlData* arg) {
  const auto ours = [&](unsigned itf) { return itf == static_cast<unsigned>(interface_.number); };
  if (request == USBDEVFS_GETDRIVER) {
    UMockdevIoctlData* d = umockdev_ioctl_data_resolve(arg, 0, sizeof(usbdevfs_getdriver), nullptr);
    if (d == nullptr) {
      client_gone(client);
      return;
    }
    auto* gd = reinterpret_cast<usbdevfs_getdriver*>(d->data);
    const bool bound = ours(gd->interface) && state_.driver_bound;
    if (bound) snprintf(gd->driver, sizeof gd->driver, "%s", interface_.kernel_driver.c_str());
    g_object_unref(d);
    complete(client, bound ? 0 : -1, bound ? 0 : ENODATA);
    return;
  }
  if (request == USBDEVFS_IOCTL) {
    UMockdevIoctlData* d = umockdev_ioctl_data_resolve(arg, 0, sizeof(usbdevfs_ioctl), nullptr);
    if (d == nullptr) {
      client_gone(client);
      return;
    }
    const int code = reinterpret_cast<usbdevfs_ioctl*>(d->data)->ioctl_code;
    g_object_unref(d);
    if (code == static_cast<int>(USBDEVFS_DISCONNECT)) {
      if (!state_.driver_bound) {
        complete(client, -1, ENODATA);
        return;
      }
      state_.driver_bound = false;
      ++state_.driver_detaches;
      complete(client, 0, 0);
    } else if (code == static_cast<int>(USBDEVFS_CONNECT)) {
      state_.driver_bound = true;
      complete(client, 1, 0);
    } else {
      complete(client, -1, ENOTTY);
    }
    return;
  }
  UMockdevIoctlData* d = umockdev_ioctl_data_resolve(arg, 0, sizeof(unsigned), nullptr);
  if (d == nullptr) {
    client_gone(client);
    return;
  }
  unsigned itf = 0;
  memcpy(&itf, d->data, sizeof itf);
  g_object_unref(d);
  if (!ours(itf)) {
    complete(client, -1, ENOENT);
  } else if (request == USBDEVFS_CLAIMINTERFACE && state_.driver_bound) {
    complete(client, -1, EBUSY);
  } else {
    state_.claimed = request == USBDEVFS_CLAIMINTERFACE;
    complete(client, 0, 0);
  }
}

// ---------------------------------------------------------------------------------------------
// URBs

const UsbEndpoint* UsbdevfsDevice::endpoint(std::uint8_t address, unsigned urb_type) const {
  for (const UsbEndpoint& e : interface_.endpoints) {
    const unsigned type = e.type == UsbEndpoint::Type::kBulk ? USBDEVFS_URB_TYPE_BULK : USBDEVFS_URB_TYPE_INTERRUPT;
    if (e.address == address && type == urb_type) return &e;
  }
  return nullptr;
}

// Control URBs go to on_control() claimed or not; bulk / interrupt URBs need the claim and one
// of the interface's endpoints (else EINVAL unclaimed, ENOENT claimed, as the arm's firmware
// answered before this was shared).
void UsbdevfsDevice::submit(UMockdevIoctlClient* client, UMockdevIoctlData* arg) {
  UMockdevIoctlData* d = umockdev_ioctl_data_resolve(arg, 0, sizeof(usbdevfs_urb), nullptr);
  if (d == nullptr) {
    client_gone(client);
    return;
  }
  usbdevfs_urb* u = urb_of(d);
  const bool control = u->type == USBDEVFS_URB_TYPE_CONTROL;
  const UsbEndpoint* ep = control ? nullptr : endpoint(u->endpoint, u->type);
  const bool too_short = control ? u->buffer_length < 8 : u->buffer_length <= 0;
  if (too_short || (!control && (ep == nullptr || !state_.claimed))) {
    g_object_unref(d);
    complete(client, -1, !control && state_.claimed ? ENOENT : EINVAL);
    return;
  }
  const auto length = static_cast<std::size_t>(u->buffer_length);
  UMockdevIoctlData* buf = umockdev_ioctl_data_resolve(d, offsetof(usbdevfs_urb, buffer), length, nullptr);
  if (buf == nullptr) {
    g_object_unref(d);
    client_gone(client);
    return;
  }
  const Urb urb{d, client, buf->data, length};
  g_object_unref(buf);  // `d` keeps it
  if (control) {
    submit_control(urb);
  } else if ((ep->address & 0x80) == 0) {
    const UrbReply r = on_out(ep->address, std::span<const std::uint8_t>(urb.buffer, urb.length));
    if (r.kind == UrbReply::Kind::kNothingYet) misuse("on_out() answered nothing_yet(): an OUT never pends");
    finish(urb, r);
  } else {
    submit_in(urb, ep->address);
  }
  complete(client, 0, 0);
}

void UsbdevfsDevice::submit_control(const Urb& urb) {
  const std::uint8_t* p = urb.buffer;
  ControlSetup s;
  s.request_type = p[0];
  s.request = p[1];
  s.value = static_cast<std::uint16_t>(p[2] | p[3] << 8);
  s.index = static_cast<std::uint16_t>(p[4] | p[5] << 8);
  s.length = static_cast<std::uint16_t>(p[6] | p[7] << 8);
  const std::size_t n = std::min<std::size_t>(s.length, urb.length - 8);
  UrbReply r = on_control(s, std::span<std::uint8_t>(urb.buffer + 8, n));
  if (r.kind == UrbReply::Kind::kNothingYet) misuse("on_control() answered nothing_yet(): control transfers never pend");
  if (r.kind == UrbReply::Kind::kDone && r.length > n) misuse("on_control() answered more than wLength bytes");
  if (r.kind == UrbReply::Kind::kDone && !s.is_in()) r.length = n;  // an accepted OUT took its whole data stage
  finish(urb, r);
}

// An IN URB: the last before the device vanishes, withheld, behind others on its endpoint (they
// are answered in order), or on_in()'s to answer now or leave pending.
void UsbdevfsDevice::submit_in(const Urb& urb, std::uint8_t endpoint) {
  if (vanish_next_in_) {
    vanish_next_in_ = false;
    unplugged_ = true;
    finish(urb, UrbReply::failed(-ESHUTDOWN));
    return;
  }
  if (withhold_ || in_waits(endpoint)) {
    pending_.push_back(urb);
    return;
  }
  const UrbReply r = on_in(endpoint, std::span<std::uint8_t>(urb.buffer, urb.length));
  if (r.kind == UrbReply::Kind::kNothingYet) {
    pending_.push_back(urb);
    return;
  }
  finish(urb, r);
}

bool UsbdevfsDevice::in_waits(std::uint8_t endpoint) const {
  return std::any_of(pending_.begin(), pending_.end(), [&](const Urb& u) { return urb_of(u.data)->endpoint == endpoint; });
}

void UsbdevfsDevice::finish(const Urb& urb, const UrbReply& reply) {
  usbdevfs_urb* u = urb_of(urb.data);
  if (reply.kind == UrbReply::Kind::kDone) {
    if (reply.length > urb.length) misuse("a hook answered more bytes than the URB's buffer holds");
    u->actual_length = static_cast<int>(reply.length);
    u->status = 0;
  } else {
    u->actual_length = 0;
    u->status = reply.status;
  }
  done_.push_back(urb);
}

}  // namespace lancet::test
