#include "arm/delta_arm.hpp"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <limits>
#include <numbers>

namespace lancet::arm {

namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kDegree = kPi / 180;

// Entry i of q, 0 past its end (release builds only; debug builds assert the length).
double joint(std::span<const double> q, int i) noexcept {
  const auto k = static_cast<std::size_t>(i);
  return k < q.size() ? q[k] : 0.0;
}

double wrap_angle(double x) noexcept {
  if (x <= -kPi) return x + 2 * kPi;
  if (x > kPi) return x - 2 * kPi;
  return x;
}

// The reach of a thigh over its shin on the z axis: there u = −r, v = −s and w = z for every leg,
// so the knee-to-effector distance D is fixed and the effector point (c − r, z) must lie between
// |D − a| and D + a from the motor axis in the u–w plane. Returns the z range (lo > hi: none).
struct AxisReach {
  double lo = 1, hi = 0;
};
AxisReach axis_reach(const DeltaGeometry& g) noexcept {
  const double y = g.f - g.s;
  if (!(std::abs(y) < g.b)) return {};
  const double reach = g.d + g.e + std::sqrt(g.b * g.b - y * y);
  const double x2 = (g.c - g.r) * (g.c - g.r);
  const double hi2 = (reach + g.a) * (reach + g.a) - x2;
  if (!(hi2 > 0)) return {};
  const double lo2 = (reach - g.a) * (reach - g.a) - x2;
  return {std::sqrt(std::max(0.0, lo2)), std::sqrt(hi2)};
}

// One leg at one joint angle: the torus p lies on, in the model frame. Its centre circle has radius
// d + e about `centre`, in the plane normal to the motor axis `v`; its tube radius is b.
struct LegTorus {
  Vec3 centre{};  // where (X, Y, Z) = 0
  Vec3 u{}, v{};  // the leg frame's u and v axes in the model frame (w is z)
  double dcentre_du = 0, dcentre_dz = 0;  // ∂centre/∂θ1 = dcentre_du · u + dcentre_dz · z
};

// Distance from p to a leg's torus (h) and its gradient, the unit shin direction (n).
struct LegDistance {
  double h = 0;
  Vec3 n{};
};

LegDistance distance(const LegTorus& t, double ring, double tube, Vec3 p) noexcept {
  const Vec3 q = p - t.centre;
  const double y = dot(q, t.v);
  const Vec3 radial = q - t.v * y;  // in the thigh's plane
  const double rho = norm(radial);
  const double m = rho - ring;
  const double dist = std::sqrt(m * m + y * y);
  LegDistance out;
  out.h = dist - tube;
  if (rho > 0 && dist > 0) out.n = (radial * (m / rho) + t.v * y) * (1.0 / dist);
  return out;
}

struct Legs {
  std::array<LegTorus, 3> torus{};
};

// p's distances to the three tori.
struct Residual {
  std::array<LegDistance, 3> leg{};
  double max_abs = 0;
};

Residual residual(const Legs& legs, const DeltaGeometry& g, Vec3 p) noexcept {
  Residual r;
  for (std::size_t i = 0; i < 3; ++i) {
    r.leg[i] = distance(legs.torus[i], g.d + g.e, g.b, p);
    const double h = std::abs(r.leg[i].h);
    if (!(h <= r.max_abs)) r.max_abs = h;  // a NaN leg too
  }
  if (!std::isfinite(r.max_abs)) r.max_abs = std::numeric_limits<double>::infinity();
  return r;
}

// (n1 × n2, n2 × n0, n0 × n1) and n0 · (n1 × n2): the adjugate columns of ∂h/∂p (rows n_i).
struct Adjugate {
  std::array<Vec3, 3> column{};
  double det = 0;
};

Adjugate adjugate(const Residual& r) noexcept {
  const Vec3 n0 = r.leg[0].n, n1 = r.leg[1].n, n2 = r.leg[2].n;
  Adjugate a;
  a.column = {cross(n1, n2), cross(n2, n0), cross(n0, n1)};
  a.det = dot(n0, a.column[0]);
  return a;
}

// Below this |det ∂h/∂p| (rows are unit vectors) the shins are taken as coplanar: singular.
constexpr double kSingularDet = 1e-12;

}  // namespace

DeltaGeometry DeltaGeometry::novint_falcon() noexcept {
  DeltaGeometry g;
  g.a = 0.060, g.b = 0.1025, g.c = 0.01443, g.d = 0.01125, g.e = 0.01125, g.f = -0.025, g.r = 0.040, g.s = -0.02309;
  g.leg_angles = {105 * kDegree, -15 * kDegree, -135 * kDegree};
  return g;
}

const char* delta_geometry_problem(const DeltaGeometry& g) noexcept {
  for (const double x : {g.a, g.b, g.c, g.d, g.e, g.f, g.r, g.s, g.leg_angles[0], g.leg_angles[1], g.leg_angles[2]})
    if (!std::isfinite(x)) return "a dimension or leg angle is not finite";
  if (!(g.a > 0)) return "a (the thigh) must be > 0";
  if (!(g.b > 0)) return "b (the shin) must be > 0";
  if (g.d < 0 || g.e < 0) return "d and e must be >= 0";
  for (std::size_t i = 0; i < 3; ++i) {
    for (std::size_t j = i + 1; j < 3; ++j) {
      const double apart = std::abs(std::remainder(g.leg_angles[i] - g.leg_angles[j], 2 * kPi));
      if (apart < kDegree) return "two leg angles are less than 1 degree apart (the legs would coincide)";
    }
  }
  const AxisReach z = axis_reach(g);
  if (!(z.lo < z.hi)) return "the legs reach no point of their common axis (|f - s| must be < b, and a + b large enough)";
  const DeltaArm arm(g);
  const auto q = arm.inverse(arm.centre());
  if (!q || !(arm.condition_number(*q) < 1e6)) return "the mechanism is singular at its centre (the shins are coplanar)";
  return nullptr;
}

DeltaArm::DeltaArm(const DeltaGeometry& g, Vec3 base_offset, DeltaAxes axes) noexcept : g_(g), base_offset_(base_offset), axes_(axes) {
  for (std::size_t i = 0; i < 3; ++i) cos_phi_[i] = std::cos(g.leg_angles[i]), sin_phi_[i] = std::sin(g.leg_angles[i]);
  const AxisReach z = axis_reach(g);
  assert(z.lo < z.hi && "DeltaArm: the geometry reaches its axis (delta_geometry_problem)");
  centre_ = {0, 0, 0.5 * (z.lo + z.hi)};
  // On the axis every leg is alike: one thigh angle, and the Jacobian there for the prediction.
  if (const auto qc = inverse(centre())) {
    centre_joint_ = (*qc)[0];
    const Jacobian jc = model_jacobian(*qc, centre_);
    for (std::size_t i = 0; i < 3; ++i) centre_jacobian_[i] = jc.column[i];
  }
}

namespace {

// The three tori at joint angles q, in the model frame.
Legs make_legs(const DeltaGeometry& g, const std::array<double, 3>& cos_phi, const std::array<double, 3>& sin_phi,
               std::span<const double> q) noexcept {
  Legs legs;
  for (std::size_t i = 0; i < 3; ++i) {
    const double c1 = std::cos(joint(q, static_cast<int>(i))), s1 = std::sin(joint(q, static_cast<int>(i)));
    LegTorus& t = legs.torus[i];
    t.u = {cos_phi[i], sin_phi[i], 0};
    t.v = {-sin_phi[i], cos_phi[i], 0};
    // Leg frame (a cos θ1 − c, −f, a sin θ1) back into the model frame: p = R_iᵀ (leg + (r, s, 0)).
    t.centre = t.u * (g.a * c1 - g.c + g.r) + t.v * (g.s - g.f) + Vec3{0, 0, g.a * s1};
    t.dcentre_du = -g.a * s1;
    t.dcentre_dz = g.a * c1;
  }
  return legs;
}

// ∂h_i/∂θ1_i: the centre moving along the thigh's swing, seen along the shin.
double dh_dtheta(const LegTorus& t, Vec3 n) noexcept { return -(dot(n, t.u) * t.dcentre_du + n.z * t.dcentre_dz); }

// Newton's method result in the model frame.
struct NewtonResult {
  Vec3 p{};
  double residual = 0;
  int iterations = 0;
};

// Damped Newton on the legs' distances from p: take the full step unless it fails to lower the
// largest distance, then halve it (up to 2⁻⁸); stop below `tolerance`, after `max_steps`, or when no
// step helps. Every accepted iterate is better than the last, so the final one is the best seen.
NewtonResult newton(const Legs& legs, const DeltaGeometry& g, Vec3 p, double tolerance, int max_steps) noexcept {
  Residual r = residual(legs, g, p);
  NewtonResult out;
  while (r.max_abs > tolerance && out.iterations < max_steps) {
    const Adjugate adj = adjugate(r);
    if (!(std::abs(adj.det) > kSingularDet)) break;
    const Vec3 step =
        (adj.column[0] * r.leg[0].h + adj.column[1] * r.leg[1].h + adj.column[2] * r.leg[2].h) * (-1.0 / adj.det);
    bool accepted = false;
    double scale = 1;
    for (int halving = 0; halving <= 8 && !accepted; ++halving, scale *= 0.5) {
      const Vec3 trial = p + step * scale;
      const Residual rt = residual(legs, g, trial);
      if (rt.max_abs < r.max_abs) p = trial, r = rt, accepted = true;
    }
    if (!accepted) break;
    ++out.iterations;
  }
  out.p = p;
  out.residual = r.max_abs;
  return out;
}

}  // namespace

DeltaSolve DeltaArm::solve(std::span<const double> q) const noexcept {
  assert(q.size() == kJoints && "DeltaArm::solve: q has 3 entries");
  const Legs legs = make_legs(g_, cos_phi_, sin_phi_, q);
  // Start from the first-order prediction about the centre (the centre itself when q is not finite).
  std::array<double, 3> dq{};
  for (std::size_t i = 0; i < 3; ++i) dq[i] = std::remainder(joint(q, static_cast<int>(i)) - centre_joint_, 2 * kPi);
  Vec3 start = centre_ + centre_jacobian_[0] * dq[0] + centre_jacobian_[1] * dq[1] + centre_jacobian_[2] * dq[2];
  if (!is_finite(start)) start = centre_;
  const NewtonResult best = newton(legs, g_, start, kTolerance, kMaxIterations);
  DeltaSolve out;
  out.position = to_device(best.p);
  out.residual = best.residual;
  out.iterations = best.iterations;
  out.converged = best.residual <= kTolerance;
  return out;
}

Vec3 DeltaArm::position(std::span<const double> q) const noexcept { return solve(q).position; }

Pose DeltaArm::forward(std::span<const double> q) const noexcept { return {position(q), Quat{}}; }

Jacobian DeltaArm::jacobian_at(std::span<const double> q, Vec3 p) const noexcept {
  Jacobian j = model_jacobian(q, to_model(p));
  for (std::size_t i = 0; i < 3; ++i) j.column[i] = turn(j.column[i]);
  return j;
}

Jacobian DeltaArm::model_jacobian(std::span<const double> q, Vec3 m) const noexcept {
  assert(q.size() == kJoints && "DeltaArm::jacobian_at: q has 3 entries");
  const Legs legs = make_legs(g_, cos_phi_, sin_phi_, q);
  const Residual r = residual(legs, g_, m);
  const Adjugate adj = adjugate(r);
  Jacobian j;
  j.n = kJoints;
  if (!(std::abs(adj.det) > kSingularDet)) return j;
  // h(p, θ) = 0 ⇒ (∂h/∂p) dp + diag(∂h_i/∂θ_i) dθ = 0 ⇒ column i = −(∂h_i/∂θ_i) · (∂h/∂p)⁻¹ e_i,
  // and (∂h/∂p)⁻¹ e_i is the adjugate's column i over the determinant.
  for (std::size_t i = 0; i < 3; ++i) j.column[i] = adj.column[i] * (-dh_dtheta(legs.torus[i], r.leg[i].n) / adj.det);
  return j;
}

Jacobian DeltaArm::jacobian(std::span<const double> q) const noexcept { return jacobian_at(q, position(q)); }

std::optional<std::array<double, 3>> DeltaArm::inverse(Vec3 p) const noexcept {
  const Vec3 m = to_model(p);
  std::array<double, 3> theta{};
  for (std::size_t i = 0; i < 3; ++i) {
    // The leg frame: (u, v, w) = R_i p + (−r, −s, 0).
    const double u = cos_phi_[i] * m.x + sin_phi_[i] * m.y - g_.r;
    const double v = -sin_phi_[i] * m.x + cos_phi_[i] * m.y - g_.s;
    const double w = m.z;
    // The shin: v + f = b cos θ3 with θ3 in (0, π), so the reach in the thigh's plane is D.
    const double y = v + g_.f;
    if (!(std::abs(y) < g_.b)) return std::nullopt;
    const double reach = g_.d + g_.e + std::sqrt(g_.b * g_.b - y * y);
    // The thigh: (x − a cos θ1)² + (w − a sin θ1)² = D² with x = u + c, i.e.
    // x cos θ1 + w sin θ1 = (x² + w² + a² − D²) / 2a: θ1 = atan2(w, x) ± acos(...), the knee outside
    // being the "−" root (libnifalcon's choice of the quadratic in tan(θ1/2)).
    const double x = u + g_.c;
    const double dist = std::hypot(x, w);
    if (!(dist > 0)) return std::nullopt;
    const double cosine = (x * x + w * w + g_.a * g_.a - reach * reach) / (2 * g_.a * dist);
    if (!(std::abs(cosine) <= 1)) return std::nullopt;
    theta[i] = wrap_angle(std::atan2(w, x) - std::acos(cosine));
  }
  return theta;
}

double DeltaArm::condition_number(std::span<const double> q) const noexcept {
  const DeltaSolve s = solve(q);
  if (!s.converged) return std::numeric_limits<double>::infinity();
  return arm::condition_number(jacobian_at(q, s.position));
}

double condition_number(const Jacobian& j) noexcept {
  const Vec3 c0 = j.column[0], c1 = j.column[1], c2 = j.column[2];
  const double det = dot(c0, cross(c1, c2));
  if (!(std::abs(det) > 0) || !std::isfinite(det)) return std::numeric_limits<double>::infinity();
  // Eigenvalues of the Gram matrix JᵀJ (Smith's closed form for a symmetric 3 × 3); the smallest
  // from det(J)² = λ1 λ2 λ3, which stays accurate when it is tiny.
  const double m00 = dot(c0, c0), m11 = dot(c1, c1), m22 = dot(c2, c2);
  const double m01 = dot(c0, c1), m02 = dot(c0, c2), m12 = dot(c1, c2);
  const double mean = (m00 + m11 + m22) / 3;
  const double off = m01 * m01 + m02 * m02 + m12 * m12;
  const double spread2 = (m00 - mean) * (m00 - mean) + (m11 - mean) * (m11 - mean) + (m22 - mean) * (m22 - mean) + 2 * off;
  if (!(spread2 > 0)) return 1;  // JᵀJ = λI
  const double spread = std::sqrt(spread2 / 6);
  const double b00 = (m00 - mean) / spread, b11 = (m11 - mean) / spread, b22 = (m22 - mean) / spread;
  const double b01 = m01 / spread, b02 = m02 / spread, b12 = m12 / spread;
  const double half_det_b =
      0.5 * (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02));
  const double angle = std::acos(std::clamp(half_det_b, -1.0, 1.0)) / 3;
  const double largest = mean + 2 * spread * std::cos(angle);
  const double smallest_guess = mean + 2 * spread * std::cos(angle + 2 * kPi / 3);
  const double middle = 3 * mean - largest - smallest_guess;
  if (!(middle > 0)) return std::numeric_limits<double>::infinity();
  const double smallest = det * det / (largest * middle);
  return std::sqrt(largest / smallest);
}

}  // namespace lancet::arm
