#include "blood/blood_compute.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace lancet::blood {

using render::make_compute_program;
namespace {

static_assert((blood::kTile & (blood::kTile - 1)) == 0, "the tile sums halve the tile: a power of two");

// Binding points, shared by every pass (a pass declares only the blocks it uses).
constexpr GLuint kArea = 0, kElevation = 1, kFilm = 2, kFirst = 3, kTo = 4, kTwin = 5, kConductance = 6, kTileFirst = 7,
                 kTileLinks = 8, kVolume = 9, kBorn = 10, kFlux = 11, kConc = 12, kSource = 13, kSink = 14, kActive = 15,
                 kReceive = 16, kTileSum = 17, kLedger = 18, kBindings = 19;

// Every pass: a workgroup is a tile (a 2-D grid of workgroups past 65535 tiles, the least
// maximum GL guarantees per dimension).
const std::string kHeader = "#version 450 core\n#define TILE " + std::to_string(blood::kTile) + R"(
layout(local_size_x = TILE) in;
uniform uint u_cells, u_tiles;
uint tile_index() { return gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x; }
// The tree sum of a shared array of TILE entries into its entry 0 (the whole workgroup takes part).
#define SUM_TILE(s) \
  memoryBarrierShared(); \
  barrier(); \
  for (uint r = uint(TILE) / 2u; r > 0u; r >>= 1) { \
    if (gl_LocalInvocationID.x < r) s[gl_LocalInvocationID.x] += s[gl_LocalInvocationID.x + r]; \
    memoryBarrierShared(); \
    barrier(); \
  }
)";

// The blocks, by name (each pass includes the ones it uses).
std::string block(const char* name, GLuint binding, const char* qualifier, const char* decl) {
  return "layout(std430, binding = " + std::to_string(binding) + ") " + qualifier + " buffer " + name + " { " + decl + "; };\n";
}

// Automaton::plan: a tile is active when a cell holds mobile blood, has a source, a sink with
// blood to take, or still sends a flux; u_all (skip_idle_tiles off) makes every tile active.
// The tiles an active tile sends to are stamped with this step's number (atomicMax: stamps only
// grow), so that the buffer needs no clearing between steps.
const std::string kPlan = kHeader + block("Film", kFilm, "readonly", "float film[]") +
                          block("First", kFirst, "readonly", "uint first[]") +
                          block("TileFirst", kTileFirst, "readonly", "uint tile_first[]") +
                          block("TileLinks", kTileLinks, "readonly", "uint tile_links[]") +
                          block("Volume", kVolume, "readonly", "float volume[]") +
                          block("Flux", kFlux, "readonly", "float flux[]") +
                          block("Source", kSource, "readonly", "float source[]") +
                          block("Sink", kSink, "readonly", "float sink[]") +
                          block("Active", kActive, "writeonly", "uint tile_on[]") +
                          block("Receive", kReceive, "", "uint receive[]") + R"(
uniform uint u_all, u_stamp;
shared uint s_on;
void main() {
  uint t = tile_index(), i = t * uint(TILE) + gl_LocalInvocationID.x;
  if (t >= u_tiles) return;
  if (gl_LocalInvocationID.x == 0u) s_on = u_all;
  memoryBarrierShared();
  barrier();
  if (i < u_cells) {
    bool on = volume[i] > film[i] || source[i] > 0.0 || (sink[i] > 0.0 && volume[i] > 0.0);
    for (uint k = first[i]; k < first[i + 1u] && !on; ++k) on = flux[k] > 0.0;
    if (on) atomicOr(s_on, 1u);
  }
  memoryBarrierShared();
  barrier();
  if (gl_LocalInvocationID.x == 0u) {
    tile_on[t] = s_on;
    if (s_on != 0u)
      for (uint l = tile_first[t]; l < tile_first[t + 1u]; ++l) atomicMax(receive[tile_links[l]], u_stamp);
  }
}
)";

// Automaton::sources_and_sinks, and the volumes added and removed summed over the tile in double
// into its running totals (only this tile's workgroup writes them: no atomics).
const std::string kSources = kHeader + block("Volume", kVolume, "", "float volume[]") + block("Born", kBorn, "", "float born[]") +
                             block("Source", kSource, "readonly", "float source[]") +
                             block("Sink", kSink, "readonly", "float sink[]") +
                             block("Active", kActive, "readonly", "uint tile_on[]") +
                             block("Ledger", kLedger, "", "dvec2 ledger[]") + R"(
uniform float u_dt, u_now;
shared dvec2 s_sum[TILE];
void main() {
  uint t = tile_index(), i = t * uint(TILE) + gl_LocalInvocationID.x;
  if (t >= u_tiles || tile_on[t] == 0u) return;  // the same for the whole workgroup
  dvec2 moved = dvec2(0.0);
  if (i < u_cells && (source[i] > 0.0 || sink[i] > 0.0)) {
    precise float vol = volume[i], b = born[i];
    if (source[i] > 0.0) {
      precise float v = source[i] * u_dt;
      vol += v;
      b += v * u_now;
      moved.x = double(v);
    }
    if (sink[i] > 0.0 && vol > 0.0) {
      precise float f = min(1.0, sink[i] * u_dt);
      precise float v = vol * f;
      moved.y = double(v);
      vol -= v;
      b -= b * f;
    }
    volume[i] = vol;
    born[i] = b;
  }
  s_sum[gl_LocalInvocationID.x] = moved;
  SUM_TILE(s_sum)
  if (gl_LocalInvocationID.x == 0u) ledger[t] += s_sum[0];
}
)";

// Automaton::fluxes: 5.17 per pipe, then the outflow scaled to the mobile volume; the sender's
// concentration for the volumes pass.
const std::string kFluxes = kHeader + block("Area", kArea, "readonly", "float area[]") +
                            block("Elevation", kElevation, "readonly", "float elevation[]") +
                            block("Film", kFilm, "readonly", "float film[]") + block("First", kFirst, "readonly", "uint first[]") +
                            block("To", kTo, "readonly", "uint to[]") +
                            block("Conductance", kConductance, "readonly", "float conductance[]") +
                            block("Volume", kVolume, "readonly", "float volume[]") +
                            block("Born", kBorn, "readonly", "float born[]") + block("Flux", kFlux, "", "float flux[]") +
                            block("Conc", kConc, "writeonly", "float conc[]") +
                            block("Active", kActive, "readonly", "uint tile_on[]") + R"(
uniform float u_dt, u_keep, u_mobility, u_ref_depth;
void main() {
  uint t = tile_index(), i = t * uint(TILE) + gl_LocalInvocationID.x;
  if (t >= u_tiles || tile_on[t] == 0u || i >= u_cells) return;
  precise float v = volume[i], a = area[i];
  precise float head = elevation[i] + v / a;
  precise float mobile = max(0.0, v - film[i]);
  precise float d = mobile / a / u_ref_depth;
  precise float m = min(1.0, d * d);
  precise float sum = 0.0;
  uint k0 = first[i], k1 = first[i + 1u];
  for (uint k = k0; k < k1; ++k) {
    uint j = to[k];
    precise float head_j = elevation[j] + volume[j] / area[j];
    precise float f = max(0.0, u_keep * flux[k] + u_dt * (u_mobility * conductance[k]) * m * (head - head_j));
    flux[k] = f;
    sum += f;
  }
  precise float outflow = sum * u_dt;
  if (outflow > mobile) {
    precise float scale = outflow > 0.0 ? 0.999999 * mobile / outflow : 0.0;
    for (uint k = k0; k < k1; ++k) {
      precise float f = flux[k] * scale;
      flux[k] = f;
    }
  }
  precise float c = v > 0.0 ? born[i] / v : 0.0;
  conc[i] = c;
}
)";

// Automaton::volumes, in the tiles an active tile sends to (this step's stamp).
const std::string kVolumes = kHeader + block("First", kFirst, "readonly", "uint first[]") + block("To", kTo, "readonly", "uint to[]") +
                             block("Twin", kTwin, "readonly", "uint twin[]") + block("Volume", kVolume, "", "float volume[]") +
                             block("Born", kBorn, "", "float born[]") + block("Flux", kFlux, "readonly", "float flux[]") +
                             block("Conc", kConc, "readonly", "float conc[]") +
                             block("Receive", kReceive, "readonly", "uint receive[]") + R"(
uniform float u_dt;
uniform uint u_stamp;
void main() {
  uint t = tile_index(), i = t * uint(TILE) + gl_LocalInvocationID.x;
  if (t >= u_tiles || receive[t] != u_stamp || i >= u_cells) return;
  precise float in_sum = 0.0, out_sum = 0.0, born_in = 0.0;
  for (uint k = first[i]; k < first[i + 1u]; ++k) {
    precise float f_in = flux[twin[k]];
    in_sum += f_in;
    born_in += f_in * conc[to[k]];
    out_sum += flux[k];
  }
  if (in_sum == 0.0 && out_sum == 0.0) return;
  precise float v = volume[i] + u_dt * in_sum - u_dt * out_sum;
  precise float b = born[i] + u_dt * born_in - u_dt * out_sum * conc[i];
  volume[i] = max(v, 0.0);
  born[i] = max(b, 0.0);
}
)";

// The blood per tile, summed in double (total_volume adds the tiles).
const std::string kMass = kHeader + block("Volume", kVolume, "readonly", "float volume[]") +
                          block("TileSum", kTileSum, "writeonly", "double tile_sum[]") + R"(
shared double s_sum[TILE];
void main() {
  uint t = tile_index(), i = t * uint(TILE) + gl_LocalInvocationID.x;
  if (t >= u_tiles) return;
  s_sum[gl_LocalInvocationID.x] = i < u_cells ? double(volume[i]) : 0.0;
  SUM_TILE(s_sum)
  if (gl_LocalInvocationID.x == 0u) tile_sum[t] = s_sum[0];
}
)";

// A buffer of `count` elements, zeros after `data` (at least 16 bytes: GL binds no empty store).
template <class T>
Buffer make_buffer(const std::vector<T>& data, std::size_t count, GLenum usage) {
  GLuint b = 0;
  glCreateBuffers(1, &b);
  glNamedBufferData(b, static_cast<GLsizeiptr>(std::max<std::size_t>(count * sizeof(T), 16)), nullptr, usage);
  glClearNamedBufferData(b, GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT, nullptr);
  if (!data.empty()) glNamedBufferSubData(b, 0, static_cast<GLsizeiptr>(std::min(data.size(), count) * sizeof(T)), data.data());
  return Buffer(b);
}

template <class T>
std::vector<T> read(const Buffer& b, std::size_t count) {
  std::vector<T> out(count);
  if (count > 0) glGetNamedBufferSubData(b.get(), 0, static_cast<GLsizeiptr>(count * sizeof(T)), out.data());
  return out;
}

GLint uniform(const Program& p, const char* name) { return glGetUniformLocation(p.get(), name); }

}  // namespace

BloodCompute::BloodCompute(const blood::Network& net, const blood::Params& params)
    : cells_(net.cells()), pipes_(net.pipes()), tiles_(net.tiles()), params_(params) {
  GLint bindings = 0;
  glGetIntegerv(GL_MAX_SHADER_STORAGE_BUFFER_BINDINGS, &bindings);
  if (bindings < static_cast<GLint>(kBindings))
    throw std::runtime_error("BloodCompute needs " + std::to_string(kBindings) + " storage-buffer bindings, GL has " +
                             std::to_string(bindings));
  plan_ = make_compute_program(kPlan);
  sources_ = make_compute_program(kSources);
  fluxes_ = make_compute_program(kFluxes);
  volumes_ = make_compute_program(kVolumes);
  mass_ = make_compute_program(kMass);
  // The reference's float, computed as it computes it (std::pow(float, float)).
  keep_ = std::pow(params_.damping, params_.dt);
  const auto cells = static_cast<GLuint>(cells_), tiles = static_cast<GLuint>(tiles_);
  for (const Program* p : {&plan_, &sources_, &fluxes_, &volumes_, &mass_}) {
    glProgramUniform1ui(p->get(), uniform(*p, "u_cells"), cells);
    glProgramUniform1ui(p->get(), uniform(*p, "u_tiles"), tiles);
    glProgramUniform1f(p->get(), uniform(*p, "u_dt"), params_.dt);
  }
  glProgramUniform1ui(plan_.get(), uniform(plan_, "u_all"), params_.skip_idle_tiles ? 0u : 1u);
  glProgramUniform1f(fluxes_.get(), uniform(fluxes_, "u_keep"), keep_);
  glProgramUniform1f(fluxes_.get(), uniform(fluxes_, "u_mobility"), params_.mobility);
  glProgramUniform1f(fluxes_.get(), uniform(fluxes_, "u_ref_depth"), params_.ref_depth);

  area_ = make_buffer(net.area, cells_, GL_STATIC_DRAW);
  elevation_ = make_buffer(net.elevation, cells_, GL_DYNAMIC_DRAW);
  film_ = make_buffer(net.film, cells_, GL_STATIC_DRAW);
  first_ = make_buffer(net.first, cells_ + 1, GL_STATIC_DRAW);
  to_ = make_buffer(net.to, pipes_, GL_STATIC_DRAW);
  twin_ = make_buffer(net.twin, pipes_, GL_STATIC_DRAW);
  conductance_ = make_buffer(net.conductance, pipes_, GL_STATIC_DRAW);
  tile_first_ = make_buffer(net.tile_first, tiles_ + 1, GL_STATIC_DRAW);
  tile_links_ = make_buffer(net.tile_links, net.tile_links.size(), GL_STATIC_DRAW);
  const std::vector<float> none;
  volume_ = make_buffer(none, cells_, GL_DYNAMIC_DRAW);
  born_ = make_buffer(none, cells_, GL_DYNAMIC_DRAW);
  flux_ = make_buffer(none, pipes_, GL_DYNAMIC_DRAW);
  conc_ = make_buffer(none, cells_, GL_DYNAMIC_DRAW);
  source_ = make_buffer(none, cells_, GL_DYNAMIC_DRAW);
  sink_ = make_buffer(none, cells_, GL_DYNAMIC_DRAW);
  const std::vector<std::uint32_t> no_tiles;
  active_ = make_buffer(no_tiles, tiles_, GL_DYNAMIC_DRAW);
  receive_ = make_buffer(no_tiles, tiles_, GL_DYNAMIC_DRAW);
  const std::vector<double> no_sums;
  tile_sum_ = make_buffer(no_sums, tiles_, GL_DYNAMIC_READ);
  ledger_ = make_buffer(no_sums, 2 * tiles_, GL_DYNAMIC_READ);
}

void BloodCompute::upload_state(const blood::State& s) {
  // Shader writes before these buffer writes land first.
  glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
  const auto put = [](const Buffer& b, const std::vector<float>& v, std::size_t count) {
    if (v.size() == count && count > 0) {
      glNamedBufferSubData(b.get(), 0, static_cast<GLsizeiptr>(count * sizeof(float)), v.data());
    } else {
      glClearNamedBufferData(b.get(), GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT, nullptr);
    }
  };
  put(volume_, s.volume, cells_);
  put(born_, s.born, cells_);
  put(flux_, s.flux, pipes_);
  put(conc_, s.conc, cells_);
  glClearNamedBufferData(ledger_.get(), GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT, nullptr);
  initial_ = 0;
  if (s.volume.size() == cells_)
    for (float v : s.volume) initial_ += v;
  time_ = s.time;
}

void BloodCompute::upload_rates(const Buffer& buffer, std::span<const float> rate, bool& any) {
  if (!rate.empty() && rate.size() != cells_) return;
  std::vector<float> r(cells_, 0.0f);
  for (std::size_t i = 0; i < rate.size(); ++i) r[i] = std::isfinite(rate[i]) ? std::max(rate[i], 0.0f) : 0.0f;
  any = std::any_of(r.begin(), r.end(), [](float x) { return x > 0.0f; });
  if (!r.empty()) glNamedBufferSubData(buffer.get(), 0, static_cast<GLsizeiptr>(r.size() * sizeof(float)), r.data());
}

void BloodCompute::set_sources(std::span<const float> rate) { upload_rates(source_, rate, any_source_); }
void BloodCompute::set_sinks(std::span<const float> rate) { upload_rates(sink_, rate, any_sink_); }

void BloodCompute::set_geometry(std::span<const float> elevation, std::span<const float> area) {
  if (cells_ == 0) return;
  if (elevation.size() == cells_)
    glNamedBufferSubData(elevation_.get(), 0, static_cast<GLsizeiptr>(cells_ * sizeof(float)), elevation.data());
  if (area.size() == cells_) {
    std::vector<float> a(area.begin(), area.end());
    for (float& x : a) x = std::max(x, 1e-12f);  // as Automaton::set_geometry
    glNamedBufferSubData(area_.get(), 0, static_cast<GLsizeiptr>(cells_ * sizeof(float)), a.data());
  }
}

void BloodCompute::bind() const {
  const GLuint buffers[kBindings] = {area_.get(),       elevation_.get(),  film_.get(),   first_.get(),    to_.get(),
                                     twin_.get(),       conductance_.get(), tile_first_.get(), tile_links_.get(), volume_.get(),
                                     born_.get(),       flux_.get(),       conc_.get(),   source_.get(),   sink_.get(),
                                     active_.get(),     receive_.get(),    tile_sum_.get(), ledger_.get()};
  glBindBuffersBase(GL_SHADER_STORAGE_BUFFER, 0, static_cast<GLsizei>(kBindings), buffers);
}

void BloodCompute::dispatch_tiles(const Program& program) const {
  const std::size_t x = std::min<std::size_t>(tiles_, 65535), y = (tiles_ + x - 1) / x;
  glUseProgram(program.get());
  glDispatchCompute(static_cast<GLuint>(x), static_cast<GLuint>(y), 1);
}

void BloodCompute::step() {
  if (cells_ == 0) return;
  if (++stamp_ == 0) {  // wrapped: older stamps would pass for this step's
    glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
    glClearNamedBufferData(receive_.get(), GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT, nullptr);
    stamp_ = 1;
  }
  bind();
  glProgramUniform1ui(plan_.get(), uniform(plan_, "u_stamp"), stamp_);
  glProgramUniform1ui(volumes_.get(), uniform(volumes_, "u_stamp"), stamp_);
  // Each pass reads what the one before wrote (as the CPU runs each over all tiles in turn).
  dispatch_tiles(plan_);
  glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
  if (any_source_ || any_sink_) {
    glProgramUniform1f(sources_.get(), uniform(sources_, "u_now"), static_cast<float>(time_));
    dispatch_tiles(sources_);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
  }
  dispatch_tiles(fluxes_);
  glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
  dispatch_tiles(volumes_);
  glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
  time_ += params_.dt;
  ++steps_;
}

blood::State BloodCompute::download() const {
  glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
  blood::State s;
  s.volume = read<float>(volume_, cells_);
  s.born = read<float>(born_, cells_);
  s.flux = read<float>(flux_, pipes_);
  s.conc = read<float>(conc_, cells_);
  s.time = time_;
  return s;
}

double BloodCompute::total_volume() const {
  if (tiles_ == 0) return 0;
  bind();
  dispatch_tiles(mass_);
  glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
  double total = 0;
  for (double t : read<double>(tile_sum_, tiles_)) total += t;
  return total;
}

blood::Ledger BloodCompute::ledger() const {
  blood::Ledger l;
  l.initial = initial_;
  l.now = total_volume();
  const std::vector<double> moved = read<double>(ledger_, 2 * tiles_);
  for (std::size_t t = 0; t < tiles_; ++t) l.sources += moved[2 * t], l.sinks += moved[2 * t + 1];
  return l;
}

std::vector<std::uint8_t> BloodCompute::tile_active() const {
  glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
  const std::vector<std::uint32_t> a = read<std::uint32_t>(active_, tiles_);
  return {a.begin(), a.end()};
}

}  // namespace lancet::blood
