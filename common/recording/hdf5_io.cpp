#include "recording/hdf5_io.hpp"

#include <hdf5.h>

#include <cstddef>
#include <algorithm>
#include <cstring>
#include <filesystem>
#include <utility>

namespace lancet::record {

namespace {

// ---------------------------------------------------------------------------------------------
// HDF5 handles as RAII, and the library's error stack kept quiet (errors are ours to word).

struct Handle {
  hid_t id = H5I_INVALID_HID;
  herr_t (*close)(hid_t) = nullptr;
  Handle() = default;
  Handle(hid_t i, herr_t (*c)(hid_t)) : id(i), close(c) {}
  Handle(Handle&& o) noexcept : id(std::exchange(o.id, H5I_INVALID_HID)), close(o.close) {}
  Handle& operator=(Handle&& o) noexcept {
    if (this != &o) {
      reset();
      id = std::exchange(o.id, H5I_INVALID_HID);
      close = o.close;
    }
    return *this;
  }
  ~Handle() { reset(); }
  void reset() {
    if (id >= 0 && close != nullptr) (void)close(id);
    id = H5I_INVALID_HID;
  }
  [[nodiscard]] bool ok() const { return id >= 0; }
  operator hid_t() const { return id; }  // NOLINT: used as the id it is
};

void quiet_hdf5() {
  static const bool once = [] {
    (void)H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
    return true;
  }();
  (void)once;
}

// The innermost message of the library's error stack ("" when none).
std::string hdf5_message() {
  std::string msg;
  (void)H5Ewalk2(
      H5E_DEFAULT, H5E_WALK_DOWNWARD,
      [](unsigned n, const H5E_error2_t* e, void* out) -> herr_t {
        if (n == 0 && e != nullptr && e->desc != nullptr) *static_cast<std::string*>(out) = e->desc;
        return 0;
      },
      &msg);
  return msg;
}

Error fail(const std::string& path, const std::string& what, ErrorCode code = ErrorCode::kInvalid) {
  const std::string lib = hdf5_message();
  return Error{code, path + ": " + what + (lib.empty() ? "" : " (HDF5: " + lib + ")")};
}

// ---------------------------------------------------------------------------------------------
// Row types.

Handle array_of(hid_t base, hsize_t n) { return {H5Tarray_create2(base, 1, &n), H5Tclose}; }

// The in-memory compound type of ToolSample, field by field (names are the file's columns).
Handle sample_type() {
  Handle t{H5Tcreate(H5T_COMPOUND, sizeof(ToolSample)), H5Tclose};
  const Handle j8 = array_of(H5T_NATIVE_DOUBLE, kMaxJoints), v3 = array_of(H5T_NATIVE_DOUBLE, 3),
               q4 = array_of(H5T_NATIVE_DOUBLE, 4), c16 = array_of(H5T_NATIVE_UINT8, kSampleCommands);
  const auto pos = [](std::size_t pose) { return pose + offsetof(Pose, position); };
  const auto ori = [](std::size_t pose) { return pose + offsetof(Pose, orientation); };
  H5Tinsert(t, "seq", offsetof(ToolSample, seq), H5T_NATIVE_UINT64);
  H5Tinsert(t, "t_ns", offsetof(ToolSample, t_ns), H5T_NATIVE_INT64);
  H5Tinsert(t, "woke_ns", offsetof(ToolSample, woke_ns), H5T_NATIVE_INT64);
  H5Tinsert(t, "n_joints", offsetof(ToolSample, n_joints), H5T_NATIVE_UINT32);
  H5Tinsert(t, "mode", offsetof(ToolSample, mode), H5T_NATIVE_UINT8);
  H5Tinsert(t, "stage", offsetof(ToolSample, stage), H5T_NATIVE_UINT8);
  H5Tinsert(t, "read_status", offsetof(ToolSample, read_status), H5T_NATIVE_UINT8);
  H5Tinsert(t, "write_status", offsetof(ToolSample, write_status), H5T_NATIVE_UINT8);
  H5Tinsert(t, "q", offsetof(ToolSample, q), j8);
  H5Tinsert(t, "qd", offsetof(ToolSample, qd), j8);
  H5Tinsert(t, "tau", offsetof(ToolSample, tau), j8);
  H5Tinsert(t, "tool_position", pos(offsetof(ToolSample, tool)), v3);
  H5Tinsert(t, "tool_orientation", ori(offsetof(ToolSample, tool)), q4);
  H5Tinsert(t, "proxy_position", pos(offsetof(ToolSample, proxy)), v3);
  H5Tinsert(t, "proxy_orientation", ori(offsetof(ToolSample, proxy)), q4);
  H5Tinsert(t, "force", offsetof(ToolSample, force), v3);
  H5Tinsert(t, "patch_version", offsetof(ToolSample, patch_version), H5T_NATIVE_UINT64);
  H5Tinsert(t, "events", offsetof(ToolSample, events), H5T_NATIVE_UINT32);
  H5Tinsert(t, "inputs", offsetof(ToolSample, inputs), H5T_NATIVE_UINT32);
  H5Tinsert(t, "payload_position", offsetof(ToolSample, payload) + offsetof(EventPayload, position), v3);
  H5Tinsert(t, "payload_magnitude", offsetof(ToolSample, payload) + offsetof(EventPayload, magnitude), H5T_NATIVE_DOUBLE);
  H5Tinsert(t, "buttons", offsetof(ToolSample, buttons), H5T_NATIVE_UINT32);
  H5Tinsert(t, "n_commands", offsetof(ToolSample, n_commands), H5T_NATIVE_UINT16);
  H5Tinsert(t, "reset_mode", offsetof(ToolSample, reset_mode), H5T_NATIVE_UINT8);
  H5Tinsert(t, "hand", offsetof(ToolSample, hand), H5T_NATIVE_UINT8);
  H5Tinsert(t, "commands", offsetof(ToolSample, commands), c16);
  H5Tinsert(t, "state_hash", offsetof(ToolSample, state_hash), H5T_NATIVE_UINT64);
  return t;
}

constexpr const char* kSampleUnits =
    "seq: servo tick; t_ns (deadline), woke_ns: ns, CLOCK_MONOTONIC; q: rad or m (prismatic); qd: rad/s or m/s; "
    "tau: N*m or N; tool_position, proxy_position, payload_position: m (tissue frame, z up); *_orientation: unit "
    "quaternion w, x, y, z; force: N (on the hand); payload_magnitude: m (radius, displacement) or N (rupture force); "
    "mode: 0 probe 1 scalpel 2 retractor 3 drill 4 swab; stage: 0 free 1 deform 2 rupture 3 cutting 4 pulling 5 "
    "drilling; events, inputs: bit sets (shared_model/messages.hpp event::, input::); commands: kind << 4 | mode; reset_mode: the tool kept through the tick's reset (255: none); "
    "hand: 0 right, 1 left (each tick has one row per hand, the right's first); state_hash: the servo state's hash every servo_hash_every ticks, else 0";

Handle frame_type() {
  Handle t{H5Tcreate(H5T_COMPOUND, sizeof(FrameRecord)), H5Tclose};
  const Handle v3 = array_of(H5T_NATIVE_DOUBLE, 3);
#define LANCET_FIELD(name, type) H5Tinsert(t, #name, offsetof(FrameRecord, name), type)
  LANCET_FIELD(frame, H5T_NATIVE_UINT64);
  LANCET_FIELD(t_ns, H5T_NATIVE_INT64);
  LANCET_FIELD(last_seq, H5T_NATIVE_UINT64);
  LANCET_FIELD(ticks, H5T_NATIVE_UINT64);
  LANCET_FIELD(blood_dt, H5T_NATIVE_DOUBLE);
  LANCET_FIELD(patch_version, H5T_NATIVE_UINT64);
  LANCET_FIELD(patch_seq, H5T_NATIVE_UINT64);
  LANCET_FIELD(patch_t_ns, H5T_NATIVE_INT64);
  LANCET_FIELD(patch_samples_applied, H5T_NATIVE_UINT64);
  LANCET_FIELD(patch_centre, v3);
  LANCET_FIELD(left_patch_version, H5T_NATIVE_UINT64);
  LANCET_FIELD(left_patch_seq, H5T_NATIVE_UINT64);
  LANCET_FIELD(left_patch_t_ns, H5T_NATIVE_INT64);
  LANCET_FIELD(left_patch_samples_applied, H5T_NATIVE_UINT64);
  LANCET_FIELD(left_patch_centre, v3);
  LANCET_FIELD(task_progress, H5T_NATIVE_DOUBLE);
  LANCET_FIELD(max_deviation, H5T_NATIVE_DOUBLE);
  LANCET_FIELD(outside, H5T_NATIVE_DOUBLE);
  LANCET_FIELD(damaged, H5T_NATIVE_UINT32);
  LANCET_FIELD(drilled_mm3, H5T_NATIVE_DOUBLE);
  LANCET_FIELD(drilled_outside_mm3, H5T_NATIVE_DOUBLE);
  LANCET_FIELD(blood_lost_ml, H5T_NATIVE_DOUBLE);
  LANCET_FIELD(blood_on_tissue_ml, H5T_NATIVE_DOUBLE);
  LANCET_FIELD(blood_swabbed_ml, H5T_NATIVE_DOUBLE);
  LANCET_FIELD(scene_hash, H5T_NATIVE_UINT64);
#undef LANCET_FIELD
  return t;
}

Handle event_type() {
  Handle t{H5Tcreate(H5T_COMPOUND, sizeof(SceneEvent)), H5Tclose};
  const Handle v3 = array_of(H5T_NATIVE_DOUBLE, 3);
  Handle name{H5Tcopy(H5T_C_S1), H5Tclose};
  H5Tset_size(name, sizeof(SceneEvent::name));
  H5Tset_strpad(name, H5T_STR_NULLTERM);
  H5Tinsert(t, "frame", offsetof(SceneEvent, frame), H5T_NATIVE_UINT64);
  H5Tinsert(t, "t_ns", offsetof(SceneEvent, t_ns), H5T_NATIVE_INT64);
  H5Tinsert(t, "kind", offsetof(SceneEvent, kind), H5T_NATIVE_UINT32);
  H5Tinsert(t, "index", offsetof(SceneEvent, index), H5T_NATIVE_UINT32);
  H5Tinsert(t, "position", offsetof(SceneEvent, position), v3);
  H5Tinsert(t, "value", offsetof(SceneEvent, value), H5T_NATIVE_DOUBLE);
  H5Tinsert(t, "name", offsetof(SceneEvent, name), name);
  return t;
}

constexpr const char* kEventUnits =
    "frame: the FrameRecord's; t_ns: ns, CLOCK_MONOTONIC; kind: 1 blood source began (value mL/s), 2 a vessel "
    "stopped bleeding, 3 a protected structure reached (index: the scenario's avoid entry), 4 bone drilled this frame "
    "(value mm^3); position: m";

constexpr const char* kFrameUnits =
    "frame: index; t_ns, patch_t_ns: ns, CLOCK_MONOTONIC; last_seq: the newest servo tick applied; ticks: the recorded "
    "rows (ticks of either hand) applied this frame; blood_dt: s; patch_*: the right hand's patch, left_patch_*: the left's; "
    "patch_centre, max_deviation: m; task_progress, outside: fraction 0..1; damaged: bit i = avoid[i] reached; "
    "drilled_mm3, drilled_outside_mm3: mm^3; blood_*_ml: mL; scene_hash: the scene's hash every scene_hash_every "
    "frames, else 0";

// ---------------------------------------------------------------------------------------------
// Attributes and strings.

// A fixed-length UTF-8 string type that holds `value` (at least one byte: HDF5 has no empty
// strings), and the bytes to write with it.
Handle string_type(const std::string& value, std::string& bytes) {
  Handle type{H5Tcopy(H5T_C_S1), H5Tclose};
  H5Tset_size(type, std::max<std::size_t>(1, value.size()));
  H5Tset_strpad(type, H5T_STR_NULLPAD);
  H5Tset_cset(type, H5T_CSET_UTF8);
  bytes = value.empty() ? std::string(1, '\0') : value;
  return type;
}

bool write_string_attr(hid_t obj, const char* name, const std::string& value) {
  std::string bytes;
  const Handle type = string_type(value, bytes);
  const Handle space{H5Screate(H5S_SCALAR), H5Sclose};
  if (H5Aexists(obj, name) > 0) H5Adelete(obj, name);
  const Handle a{H5Acreate2(obj, name, type, space, H5P_DEFAULT, H5P_DEFAULT), H5Aclose};
  return a.ok() && H5Awrite(a, type, bytes.data()) >= 0;
}

template <class T>
bool write_attr(hid_t obj, const char* name, hid_t type, T value) {
  const Handle space{H5Screate(H5S_SCALAR), H5Sclose};
  if (H5Aexists(obj, name) > 0) H5Adelete(obj, name);
  const Handle a{H5Acreate2(obj, name, type, space, H5P_DEFAULT, H5P_DEFAULT), H5Aclose};
  return a.ok() && H5Awrite(a, type, &value) >= 0;
}

bool write_string_dataset(hid_t loc, const char* name, const std::string& value) {
  std::string bytes;
  const Handle type = string_type(value, bytes);
  const Handle space{H5Screate(H5S_SCALAR), H5Sclose};
  const Handle d{H5Dcreate2(loc, name, type, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Dclose};
  return d.ok() && H5Dwrite(d, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, bytes.data()) >= 0;
}

// A fixed- or variable-length string from an attribute or a dataset (`read` reads it with a type).
template <class GetType, class Read>
bool read_string(GetType get_type, Read read, std::string& out) {
  const Handle type{get_type(), H5Tclose};
  if (!type.ok() || H5Tget_class(type) != H5T_STRING) return false;
  if (H5Tis_variable_str(type) > 0) {
    const Handle mem{H5Tcopy(H5T_C_S1), H5Tclose};
    H5Tset_size(mem, H5T_VARIABLE);
    H5Tset_cset(mem, H5Tget_cset(type));
    char* s = nullptr;
    if (read(mem, &s) < 0) return false;
    out = s != nullptr ? s : "";
    H5free_memory(s);
    return true;
  }
  const std::size_t n = H5Tget_size(type);
  std::string buf(n, '\0');
  const Handle mem{H5Tcopy(H5T_C_S1), H5Tclose};
  H5Tset_size(mem, n);
  H5Tset_strpad(mem, H5T_STR_NULLPAD);
  H5Tset_cset(mem, H5Tget_cset(type));  // HDF5 does not convert between ASCII and UTF-8
  if (read(mem, buf.data()) < 0) return false;
  buf.resize(std::strlen(buf.c_str()));
  out = std::move(buf);
  return true;
}

bool read_string_attr(hid_t obj, const char* name, std::string& out) {
  if (H5Aexists(obj, name) <= 0) return false;
  const Handle a{H5Aopen(obj, name, H5P_DEFAULT), H5Aclose};
  if (!a.ok()) return false;
  return read_string([&] { return H5Aget_type(a); }, [&](hid_t mem, void* buf) { return H5Aread(a, mem, buf); }, out);
}

template <class T>
bool read_attr(hid_t obj, const char* name, hid_t type, T& out) {
  if (H5Aexists(obj, name) <= 0) return false;
  const Handle a{H5Aopen(obj, name, H5P_DEFAULT), H5Aclose};
  return a.ok() && H5Aread(a, type, &out) >= 0;
}

bool read_string_dataset(hid_t loc, const char* name, std::string& out) {
  if (H5Lexists(loc, name, H5P_DEFAULT) <= 0) return false;
  const Handle d{H5Dopen2(loc, name, H5P_DEFAULT), H5Dclose};
  if (!d.ok()) return false;
  return read_string([&] { return H5Dget_type(d); },
                     [&](hid_t mem, void* buf) { return H5Dread(d, mem, H5S_ALL, H5S_ALL, H5P_DEFAULT, buf); }, out);
}

// Opaque bytes (the servo's model, patches: read back only by this build's layout), deflated.
bool write_bytes(hid_t loc, const char* name, const void* data, std::size_t n) {
  const hsize_t dims = n, chunk = std::max<hsize_t>(1, std::min<hsize_t>(n, 65536));
  const Handle space{H5Screate_simple(1, &dims, nullptr), H5Sclose};
  const Handle props{H5Pcreate(H5P_DATASET_CREATE), H5Pclose};
  if (n > 0) {
    H5Pset_chunk(props, 1, &chunk);
    H5Pset_deflate(props, 6);
  }
  const Handle d{H5Dcreate2(loc, name, H5T_NATIVE_UINT8, space, H5P_DEFAULT, props, H5P_DEFAULT), H5Dclose};
  return d.ok() && (n == 0 || H5Dwrite(d, H5T_NATIVE_UINT8, H5S_ALL, H5S_ALL, H5P_DEFAULT, data) >= 0);
}

bool write_u64s(hid_t loc, const char* name, const std::vector<std::uint64_t>& v) {
  const hsize_t dims = v.size();
  const Handle space{H5Screate_simple(1, &dims, nullptr), H5Sclose};
  const Handle d{H5Dcreate2(loc, name, H5T_NATIVE_UINT64, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Dclose};
  return d.ok() && (v.empty() || H5Dwrite(d, H5T_NATIVE_UINT64, H5S_ALL, H5S_ALL, H5P_DEFAULT, v.data()) >= 0);
}

// A 1-D dataset's length (-1: missing or not 1-D).
long long extent_1d(hid_t loc, const char* name) {
  if (H5Lexists(loc, name, H5P_DEFAULT) <= 0) return -1;
  const Handle d{H5Dopen2(loc, name, H5P_DEFAULT), H5Dclose};
  const Handle space{d.ok() ? H5Dget_space(d) : H5I_INVALID_HID, H5Sclose};
  hsize_t dims = 0;
  if (!space.ok() || H5Sget_simple_extent_ndims(space) != 1) return -1;
  H5Sget_simple_extent_dims(space, &dims, nullptr);
  return static_cast<long long>(dims);
}

bool read_u64s(hid_t loc, const char* name, std::vector<std::uint64_t>& out, std::size_t max) {
  const long long n = extent_1d(loc, name);
  if (n < 0 || static_cast<std::size_t>(n) > max) return false;
  out.assign(static_cast<std::size_t>(n), 0);
  if (n == 0) return true;
  const Handle d{H5Dopen2(loc, name, H5P_DEFAULT), H5Dclose};
  return d.ok() && H5Dread(d, H5T_NATIVE_UINT64, H5S_ALL, H5S_ALL, H5P_DEFAULT, out.data()) >= 0;
}

bool read_bytes(hid_t loc, const char* name, void* data, std::size_t n) {
  if (H5Lexists(loc, name, H5P_DEFAULT) <= 0) return false;
  const Handle d{H5Dopen2(loc, name, H5P_DEFAULT), H5Dclose};
  const Handle space{d.ok() ? H5Dget_space(d) : H5I_INVALID_HID, H5Sclose};
  hsize_t dims = 0;
  if (!space.ok() || H5Sget_simple_extent_ndims(space) != 1) return false;
  H5Sget_simple_extent_dims(space, &dims, nullptr);
  return dims == n && H5Dread(d, H5T_NATIVE_UINT8, H5S_ALL, H5S_ALL, H5P_DEFAULT, data) >= 0;
}

// An extendible, chunked, deflated table of `type` rows.
Handle create_table(hid_t loc, const char* name, hid_t type, hsize_t chunk, const char* units) {
  const hsize_t dims = 0, maxdims = H5S_UNLIMITED;
  const Handle space{H5Screate_simple(1, &dims, &maxdims), H5Sclose};
  const Handle props{H5Pcreate(H5P_DATASET_CREATE), H5Pclose};
  H5Pset_chunk(props, 1, &chunk);
  H5Pset_shuffle(props);
  H5Pset_deflate(props, 1);
  Handle d{H5Dcreate2(loc, name, type, space, H5P_DEFAULT, props, H5P_DEFAULT), H5Dclose};
  if (d.ok() && !write_string_attr(d, "units", units)) d.reset();
  return d;
}

bool append_rows(hid_t dataset, hid_t type, hsize_t& rows, const void* data, hsize_t n) {
  if (n == 0) return true;
  const hsize_t total = rows + n;
  if (H5Dset_extent(dataset, &total) < 0) return false;
  const Handle file_space{H5Dget_space(dataset), H5Sclose};
  if (H5Sselect_hyperslab(file_space, H5S_SELECT_SET, &rows, nullptr, &n, nullptr) < 0) return false;
  const Handle mem_space{H5Screate_simple(1, &n, nullptr), H5Sclose};
  if (H5Dwrite(dataset, type, mem_space, file_space, H5P_DEFAULT, data) < 0) return false;
  rows = total;
  return true;
}

// Rows a table may claim before the reader calls it corrupt: 24 hours of servo ticks.
constexpr hsize_t kMaxRows = 24ull * 3600 * 1000;

template <class Row>
bool read_table(hid_t file, const char* name, hid_t type, std::vector<Row>& out, std::string& why) {
  if (H5Lexists(file, name, H5P_DEFAULT) <= 0) {
    why = std::string(name) + ": missing";
    return false;
  }
  const Handle d{H5Dopen2(file, name, H5P_DEFAULT), H5Dclose};
  const Handle space{d.ok() ? H5Dget_space(d) : H5I_INVALID_HID, H5Sclose};
  if (!space.ok() || H5Sget_simple_extent_ndims(space) != 1) {
    why = std::string(name) + ": not a table of rows";
    return false;
  }
  hsize_t n = 0;
  H5Sget_simple_extent_dims(space, &n, nullptr);
  if (n > kMaxRows) {
    why = std::string(name) + ": " + std::to_string(n) + " rows, more than a recording holds (" + std::to_string(kMaxRows) + ")";
    return false;
  }
  out.assign(static_cast<std::size_t>(n), Row{});
  if (n > 0 && H5Dread(d, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, out.data()) < 0) {
    why = std::string(name) + ": cannot read its " + std::to_string(n) + " rows (truncated or corrupted?)";
    return false;
  }
  return true;
}

// A recording cut short holds what its writer flushed: rows a table was extended by but never
// got (a crash between the two) read back as zeros and go, then every frame that applied a tick
// the file does not hold, the ticks no frame it holds applied (format 2), and the events of
// frames that went. The counts the finished file would
// have carried are counted here.
// Each hand's ticks are consecutive: a jump in a hand's seq is a gap (last: by hand, 0 = none yet).
void count_gap(const ToolSample& s, std::uint64_t (&last)[kHandCount], std::uint64_t& gaps, std::uint64_t& lost) {
  const std::size_t h = hand_slot(s.hand);
  if (last[h] != 0 && s.seq != last[h] + 1) {
    ++gaps;
    if (s.seq > last[h]) lost += s.seq - last[h] - 1;
  }
  last[h] = s.seq;
}

void trim_cut_short(Recording& r) {
  while (!r.samples.empty() && r.samples.back().seq == 0) r.samples.pop_back();
  while (!r.frames.empty() && r.frames.back().t_ns == 0) r.frames.pop_back();
  while (!r.events.empty() && r.events.back().t_ns == 0) r.events.pop_back();
  if (r.format_version >= 2) {  // frames count their ticks
    std::uint64_t ticks = 0;
    std::size_t keep = 0;
    while (keep < r.frames.size() && ticks + r.frames[keep].ticks <= r.samples.size()) ticks += r.frames[keep++].ticks;
    r.frames.resize(keep);
    r.samples.resize(static_cast<std::size_t>(ticks));  // and the ticks no kept frame applied
  } else {
    const std::uint64_t last_seq = r.samples.empty() ? 0 : r.samples.back().seq;
    while (!r.frames.empty() && r.frames.back().last_seq > last_seq) r.frames.pop_back();
  }
  const std::uint64_t frames = r.frames.size();
  while (!r.events.empty() && r.events.back().frame >= frames) r.events.pop_back();
  r.samples_lost = 0, r.gaps = 0;
  std::uint64_t last[kHandCount] = {};
  for (const ToolSample& s : r.samples) count_gap(s, last, r.gaps, r.samples_lost);
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Recorder

struct Recorder::File {
  Handle file, samples, frames, events, sample_type, frame_type, event_type;
  hsize_t sample_rows = 0, frame_rows = 0, event_rows = 0;
};

Result<std::unique_ptr<Recorder>> Recorder::create(const std::string& path, const Recording& meta) {
  quiet_hdf5();
  auto f = std::make_unique<File>();
  // SWMR (single writer, multiple readers) needs the latest file format; in it, what the writer
  // has flushed stays readable whatever happens to the writer afterwards.
  const Handle fapl{H5Pcreate(H5P_FILE_ACCESS), H5Pclose};
  H5Pset_libver_bounds(fapl, H5F_LIBVER_LATEST, H5F_LIBVER_LATEST);
  f->file = Handle{H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, fapl), H5Fclose};
  if (!f->file.ok()) return fail(path, "cannot create the recording", ErrorCode::kSystem);
  if (meta.hands < 1 || meta.hands > kHandCount)
    return Error{ErrorCode::kInvalid, path + ": hands: expected 1 or 2, found " + std::to_string(meta.hands)};
  if (meta.first_patch_versions.size() != meta.first_patches.size())
    return Error{ErrorCode::kInvalid, path + ": first_patch_versions and first_patches differ in length"};
  f->sample_type = sample_type();
  f->frame_type = frame_type();
  f->event_type = event_type();
  const hid_t root = f->file;
  bool ok = write_attr(root, "format_version", H5T_NATIVE_UINT32, kFormatVersion) &&
            write_string_attr(root, "lancet_version", meta.lancet_version) &&
            write_attr(root, "layout_hash", H5T_NATIVE_UINT64, meta.layout_hash) &&
            write_attr(root, "recorded_layout_hash", H5T_NATIVE_UINT64, meta.recorded_layout_hash) &&
            write_attr(root, "protocol", H5T_NATIVE_UINT64, meta.protocol) && write_string_attr(root, "created", meta.created) &&
            write_string_attr(root, "scenario_name", meta.scenario_name) &&
            write_string_attr(root, "scenario_file", meta.scenario_file) &&
            write_attr(root, "period_ns", H5T_NATIVE_INT64, meta.period_ns) &&
            write_attr(root, "servo_hash_every", H5T_NATIVE_UINT32, meta.servo_hash_every) &&
            write_attr(root, "scene_hash_every", H5T_NATIVE_UINT32, meta.scene_hash_every) &&
            write_string_attr(root, "tissue", meta.tissue) && write_string_attr(root, "volume_path", meta.volume_path) &&
            write_attr(root, "patch_radius_m", H5T_NATIVE_DOUBLE, meta.patch_radius) &&
            write_attr(root, "hands", H5T_NATIVE_UINT32, meta.hands) &&
            // The counts and complete = 1 are written by finish(); here, so that they exist before
            // SWMR mode (which allows no new attributes), their values for a file cut short.
            write_attr(root, "samples", H5T_NATIVE_UINT64, std::uint64_t{0}) &&
            write_attr(root, "frames", H5T_NATIVE_UINT64, std::uint64_t{0}) &&
            write_attr(root, "events", H5T_NATIVE_UINT64, std::uint64_t{0}) &&
            write_attr(root, "samples_lost", H5T_NATIVE_UINT64, std::uint64_t{0}) &&
            write_attr(root, "gaps", H5T_NATIVE_UINT64, std::uint64_t{0}) &&
            write_attr(root, "complete", H5T_NATIVE_UINT32, std::uint32_t{0});
  if (ok) {
    const Handle g{H5Gcreate2(root, "meta", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Gclose};
    ok = g.ok() && write_string_dataset(g, "scenario", meta.scenario_toml) && write_string_dataset(g, "arm_config", meta.arm_config) &&
         write_bytes(g, "servo_model", &meta.servo_model[0], sizeof meta.servo_model[0]) &&
         (meta.hands < 2 || (write_bytes(g, "servo_model_left", &meta.servo_model[1], sizeof meta.servo_model[1]) &&
                             write_string_dataset(g, "arm_config_left", meta.left_arm_config))) &&
         write_u64s(g, "first_patch_versions", meta.first_patch_versions) &&
         write_bytes(g, "first_patches", meta.first_patches.data(), meta.first_patches.size() * sizeof(TissuePatch));
  }
  if (ok) {
    const Handle servo{H5Gcreate2(root, "servo", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Gclose};
    const Handle viz{H5Gcreate2(root, "viz", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Gclose};
    if (servo.ok() && viz.ok()) {
      f->samples = create_table(servo, "samples", f->sample_type, 1024, kSampleUnits);
      f->frames = create_table(viz, "frames", f->frame_type, 256, kFrameUnits);
      f->events = create_table(viz, "events", f->event_type, 64, kEventUnits);
    }
    ok = f->samples.ok() && f->frames.ok() && f->events.ok();
  }
  if (!ok) return fail(path, "cannot write the recording's header", ErrorCode::kSystem);
  if (H5Fstart_swmr_write(f->file) < 0) return fail(path, "cannot start writing in SWMR mode", ErrorCode::kSystem);
  (void)H5Fflush(f->file, H5F_SCOPE_GLOBAL);
  return std::unique_ptr<Recorder>(new Recorder(path, std::move(f)));
}

Recorder::Recorder(std::string path, std::unique_ptr<File> file) : path_(std::move(path)), file_(std::move(file)) {
  thread_ = std::thread([this] { run(); });
}

Recorder::~Recorder() { (void)finish(); }

void Recorder::add_samples(std::span<const ToolSample> samples) {
  const std::lock_guard lock(mutex_);
  if (finished_) return;
  for (const ToolSample& s : samples) {
    count_gap(s, last_seq_, gaps_, lost_);
    ++n_samples_;
  }
  samples_.insert(samples_.end(), samples.begin(), samples.end());
  if (samples_.size() >= 1024) wake_.notify_one();
}

void Recorder::add_frame(const FrameRecord& frame) {
  const std::lock_guard lock(mutex_);
  if (finished_) return;
  frames_.push_back(frame);
  ++n_frames_;
}

void Recorder::add_event(const SceneEvent& event) {
  const std::lock_guard lock(mutex_);
  if (finished_) return;
  events_.push_back(event);
  events_.back().name[sizeof(SceneEvent::name) - 1] = '\0';
  ++n_events_;
}

std::uint64_t Recorder::samples() const noexcept {
  const std::lock_guard lock(mutex_);
  return n_samples_;
}
std::uint64_t Recorder::frames() const noexcept {
  const std::lock_guard lock(mutex_);
  return n_frames_;
}
std::uint64_t Recorder::samples_lost() const noexcept {
  const std::lock_guard lock(mutex_);
  return lost_;
}
std::uint64_t Recorder::gaps() const noexcept {
  const std::lock_guard lock(mutex_);
  return gaps_;
}
std::uint64_t Recorder::samples_flushed() const noexcept {
  const std::lock_guard lock(mutex_);
  return n_flushed_;
}

Result<void> Recorder::flush_pending(std::vector<ToolSample>& samples, std::vector<FrameRecord>& frames,
                                     std::vector<SceneEvent>& events) {
  File& f = *file_;
  if (!append_rows(f.samples, f.sample_type, f.sample_rows, samples.data(), samples.size()) ||
      !append_rows(f.frames, f.frame_type, f.frame_rows, frames.data(), frames.size()) ||
      !append_rows(f.events, f.event_type, f.event_rows, events.data(), events.size()))
    return fail(path_, "cannot append to the recording (disk full?)", ErrorCode::kSystem);
  samples.clear();
  frames.clear();
  events.clear();
  (void)H5Fflush(f.file, H5F_SCOPE_GLOBAL);
  return Result<void>::success();
}

void Recorder::run() {
  std::vector<ToolSample> samples;
  std::vector<FrameRecord> frames;
  std::vector<SceneEvent> events;
  std::unique_lock lock(mutex_);
  for (;;) {
    // A chunk's worth, or a quarter second, whichever comes first.
    wake_.wait_for(lock, std::chrono::milliseconds(250), [&] { return stop_ || samples_.size() >= 1024; });
    samples.swap(samples_);
    frames.swap(frames_);
    events.swap(events_);
    const bool stop = stop_;
    const std::size_t n = samples.size();
    lock.unlock();
    const Result<void> r = flush_pending(samples, frames, events);
    lock.lock();
    if (r.ok()) n_flushed_ += n;
    if (!r.ok() && error_.empty()) error_ = r.error().message;
    if (stop && samples_.empty() && frames_.empty() && events_.empty()) return;
  }
}

Result<void> Recorder::finish() {
  {
    const std::lock_guard lock(mutex_);
    if (finished_) return error_.empty() ? Result<void>::success() : Error{ErrorCode::kSystem, error_};
    finished_ = true;
    stop_ = true;
  }
  wake_.notify_one();
  if (thread_.joinable()) thread_.join();
  File& f = *file_;
  f.samples.reset(), f.frames.reset(), f.events.reset(), f.sample_type.reset(), f.frame_type.reset(), f.event_type.reset();
  f.file.reset();
  // Out of SWMR mode: the final counts and complete = 1 (new attribute values), in the file
  // opened again the ordinary way.
  const Handle fapl{H5Pcreate(H5P_FILE_ACCESS), H5Pclose};
  H5Pset_libver_bounds(fapl, H5F_LIBVER_LATEST, H5F_LIBVER_LATEST);
  const Handle file{H5Fopen(path_.c_str(), H5F_ACC_RDWR, fapl), H5Fclose};
  const bool ok = file.ok() && write_attr(file, "samples", H5T_NATIVE_UINT64, n_samples_) &&
                  write_attr(file, "frames", H5T_NATIVE_UINT64, n_frames_) &&
                  write_attr(file, "events", H5T_NATIVE_UINT64, n_events_) &&
                  write_attr(file, "samples_lost", H5T_NATIVE_UINT64, lost_) && write_attr(file, "gaps", H5T_NATIVE_UINT64, gaps_) &&
                  write_attr(file, "complete", H5T_NATIVE_UINT32, std::uint32_t{1});
  if (!ok && error_.empty()) error_ = fail(path_, "cannot write the recording's final counts").message;
  return error_.empty() ? Result<void>::success() : Error{ErrorCode::kSystem, error_};
}

Result<void> write_recording(const std::string& path, const Recording& r) {
  auto rec = Recorder::create(path, r);
  if (!rec.ok()) return rec.error();
  rec.value()->add_samples(r.samples);
  for (const FrameRecord& f : r.frames) rec.value()->add_frame(f);
  for (const SceneEvent& e : r.events) rec.value()->add_event(e);
  return rec.value()->finish();
}

// ---------------------------------------------------------------------------------------------
// Reading

Result<Recording> read_recording(const std::string& path) {
  quiet_hdf5();
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) return Error{ErrorCode::kNotFound, path + ": no such file"};
  if (H5Fis_hdf5(path.c_str()) <= 0)
    return Error{ErrorCode::kInvalid, path + ": not an HDF5 file, or truncated or corrupted (its superblock cannot be read)"};
  Handle file{H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose};
  // A file whose SWMR writer never closed it (killed, power lost) is still marked open for writing:
  // it opens as a SWMR reader would, with everything the writer flushed.
  if (!file.ok()) file = Handle{H5Fopen(path.c_str(), H5F_ACC_RDONLY | H5F_ACC_SWMR_READ, H5P_DEFAULT), H5Fclose};
  if (!file.ok()) return fail(path, "cannot open as HDF5 (truncated or corrupted?)");
  Recording r;
  std::uint32_t complete = 0;
  if (!read_attr(file, "format_version", H5T_NATIVE_UINT32, r.format_version))
    return Error{ErrorCode::kInvalid, path + ": attribute format_version: missing (not a Lancet recording)"};
  if (r.format_version != kFormatVersion && r.format_version != 1)
    return Error{ErrorCode::kInvalid, path + ": attribute format_version: expected 1 or " + std::to_string(kFormatVersion) +
                                          ", found " + std::to_string(r.format_version)};
  // Version 1 files were written whole or not at all: one not finished is refused as before.
  if (!read_attr(file, "complete", H5T_NATIVE_UINT32, complete) || (complete != 1 && r.format_version == 1))
    return Error{ErrorCode::kInvalid, path + ": the recording was not finished (attribute complete is missing): the "
                                             "recorder stopped before closing it"};
  r.cut_short = complete != 1;
  std::uint64_t n_samples = 0, n_frames = 0, n_events = 0;
  const char* missing = nullptr;
  const auto need = [&](bool ok, const char* name) {
    if (!ok && missing == nullptr) missing = name;
  };
  need(read_string_attr(file, "lancet_version", r.lancet_version), "lancet_version");
  need(read_attr(file, "layout_hash", H5T_NATIVE_UINT64, r.layout_hash), "layout_hash");
  if (!read_attr(file, "recorded_layout_hash", H5T_NATIVE_UINT64, r.recorded_layout_hash)) r.recorded_layout_hash = 0;
  need(read_attr(file, "protocol", H5T_NATIVE_UINT64, r.protocol), "protocol");
  need(read_string_attr(file, "created", r.created), "created");
  need(read_string_attr(file, "scenario_name", r.scenario_name), "scenario_name");
  need(read_string_attr(file, "scenario_file", r.scenario_file), "scenario_file");
  need(read_attr(file, "period_ns", H5T_NATIVE_INT64, r.period_ns), "period_ns");
  need(read_attr(file, "servo_hash_every", H5T_NATIVE_UINT32, r.servo_hash_every), "servo_hash_every");
  need(read_attr(file, "scene_hash_every", H5T_NATIVE_UINT32, r.scene_hash_every), "scene_hash_every");
  need(read_attr(file, "samples", H5T_NATIVE_UINT64, n_samples), "samples");
  need(read_attr(file, "frames", H5T_NATIVE_UINT64, n_frames), "frames");
  need(read_attr(file, "events", H5T_NATIVE_UINT64, n_events), "events");
  need(read_attr(file, "samples_lost", H5T_NATIVE_UINT64, r.samples_lost), "samples_lost");
  need(read_attr(file, "gaps", H5T_NATIVE_UINT64, r.gaps), "gaps");
  need(read_string_attr(file, "tissue", r.tissue), "tissue");
  need(read_string_attr(file, "volume_path", r.volume_path), "volume_path");
  need(read_attr(file, "patch_radius_m", H5T_NATIVE_DOUBLE, r.patch_radius), "patch_radius_m");
  std::uint64_t v1_first_version = 0;
  if (r.format_version == 1) need(read_attr(file, "first_patch_version", H5T_NATIVE_UINT64, v1_first_version), "first_patch_version");
  if (missing != nullptr) return fail(path, std::string("root attribute ") + missing + ": missing or unreadable");
  if (!read_string_dataset(file, "/meta/scenario", r.scenario_toml) || !read_string_dataset(file, "/meta/arm_config", r.arm_config))
    return fail(path, "/meta/scenario or /meta/arm_config: missing or unreadable");
  // Files from before two hands have no hands attribute: one hand, the right.
  if (!read_attr(file, "hands", H5T_NATIVE_UINT32, r.hands)) r.hands = 1;
  if (r.hands < 1 || r.hands > kHandCount)
    return fail(path, "root attribute hands: expected 1 or 2, found " + std::to_string(r.hands));
  if (!read_bytes(file, "/meta/servo_model", &r.servo_model[0], sizeof r.servo_model[0]))
    return fail(path, "/meta/servo_model: missing, or not " + std::to_string(sizeof r.servo_model[0]) + " bytes (recorded by another layout)");
  if (r.hands == 2 && (!read_bytes(file, "/meta/servo_model_left", &r.servo_model[1], sizeof r.servo_model[1]) ||
                       !read_string_dataset(file, "/meta/arm_config_left", r.left_arm_config)))
    return fail(path, "/meta/servo_model_left or /meta/arm_config_left: missing, or not the size this build's layout gives (hands = 2)");
  if (r.format_version == 1) {
    auto first = std::make_unique<TissuePatch>();
    if (!read_bytes(file, "/meta/first_patch", first.get(), sizeof(TissuePatch)))
      return fail(path, "/meta/first_patch: missing, or not " + std::to_string(sizeof(TissuePatch)) + " bytes (recorded by another layout)");
    if (v1_first_version != 0) {
      r.first_patch_versions.push_back(v1_first_version);
      r.first_patches.push_back(*first);
    }
  } else {
    // At most 64 first patches (a recording keeps 8): a bigger claim is a corrupt file.
    if (!read_u64s(file, "/meta/first_patch_versions", r.first_patch_versions, 64))
      return fail(path, "/meta/first_patch_versions: missing, unreadable or more than 64");
    r.first_patches.resize(r.first_patch_versions.size());
    if (!read_bytes(file, "/meta/first_patches", r.first_patches.data(), r.first_patches.size() * sizeof(TissuePatch)))
      return fail(path, "/meta/first_patches: missing, or not " + std::to_string(r.first_patches.size()) + " patches of " +
                            std::to_string(sizeof(TissuePatch)) + " bytes (recorded by another layout)");
  }
  std::string why;
  const Handle st = sample_type(), ft = frame_type(), et = event_type();
  if (!read_table(file, "/servo/samples", st, r.samples, why) || !read_table(file, "/viz/frames", ft, r.frames, why) ||
      !read_table(file, "/viz/events", et, r.events, why))
    return fail(path, why);
  if (r.cut_short) {
    trim_cut_short(r);
    return r;
  }
  if (r.samples.size() != n_samples || r.frames.size() != n_frames || r.events.size() != n_events)
    return Error{ErrorCode::kInvalid, path + ": /servo/samples has " + std::to_string(r.samples.size()) + " rows and /viz/frames " +
                                          std::to_string(r.frames.size()) + " and /viz/events " + std::to_string(r.events.size()) +
                                          ", the root attributes say " + std::to_string(n_samples) + ", " + std::to_string(n_frames) +
                                          " and " + std::to_string(n_events)};
  return r;
}

}  // namespace lancet::record
