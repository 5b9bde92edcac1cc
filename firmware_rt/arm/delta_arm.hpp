#pragma once
// DeltaArm: R. E. Stamper's (1997) three-leg translational parallel mechanism, the Novint Falcon's
// kinematics. Three motors on a fixed base each swing a thigh; each thigh carries a parallelogram
// shin down to the moving effector, which can translate but not turn. Joints q = the three thigh
// angles θ1 (rad); the tool point is the effector centre.
//
// Frames. The base frame (the model's own, before base_offset) has its z axis on the legs' common
// axis, pointing from the motors to the workspace. Leg i's frame (u, v, w) is the base frame turned
// by its leg angle φ_i about z and moved by (−r, −s, 0):
//   (u, v, w) = R_i p + (−r, −s, 0),   R_i = [[cos φ_i, sin φ_i, 0], [−sin φ_i, cos φ_i, 0], [0, 0, 1]]
// (as libnifalcon). Leg i's motor axis is the leg frame's v axis; its thigh (length a) turns in the
// u–w plane, θ1 measured from +u toward +w. The shin is a parallelogram with sides b; θ3 ∈ (0, π) is
// its angle from the v axis.
//
// Constraint of leg i (Stamper's, with D = d + e + b sin θ3 the knee-to-effector reach in the u–w
// plane, and v + f = b cos θ3):
//   g_i(p, θ1) = (u + c − a cos θ1)² + (w − a sin θ1)² − D² = 0.
// With (X, Y, Z) = (u + c − a cos θ1, v + f, w − a sin θ1) this says that p lies on a torus: the
// circle of radius d + e about the point (a cos θ1 − c, −f, a sin θ1) in the plane of the thigh,
// swept with radius b. Forward kinematics meets three tori (no closed form); this model solves the
// signed distance to each torus, h_i = √((√(X² + Z²) − (d + e))² + Y²) − b, for p by Newton's method.
// h_i = 0 exactly where g_i = 0 with sin θ3 > 0, and its gradient is the unit shin direction, which
// keeps the iteration well scaled; the Jacobian by implicit differentiation is the same for either
// form.
//
// Everything here is fixed-size and never allocates; position, forward, jacobian, inverse and
// condition_number are real-time safe and deterministic: the same q gives the same bits whatever
// was computed before (Newton's start depends on q alone), as replay needs.

#include <array>
#include <cstdint>
#include <optional>
#include <span>

#include "arm/jacobian.hpp"
#include "lancet/shared_model/geometry.hpp"

namespace lancet::arm {

/// Stamper's dimensions (his figure; libnifalcon's FalconGeometry.h names them the same).
struct DeltaGeometry {
  double a = 0;  ///< m, thigh: motor axis to knee, > 0
  double b = 0;  ///< m, shin: the parallelogram's long side, > 0
  double c = 0;  ///< m, effector centre to the shin's effector-side joint, along u
  double d = 0;  ///< m, shin's effector-side joint to the effector, along the thigh plane's reach
  double e = 0;  ///< m, knee to the shin's knee-side joint, along the thigh plane's reach
  double f = 0;  ///< m, effector centre to the shin's effector-side joint, along v
  double r = 0;  ///< m, base origin to the leg frame's origin, along u
  double s = 0;  ///< m, base origin to the leg frame's origin, along v
  std::array<double, 3> leg_angles{};  ///< rad, φ_i: each leg frame's turn about z

  /// The Novint Falcon's published values (libnifalcon): a = 60, b = 102.5, c = 14.43,
  /// d = e = 11.25, f = −25, r = 40, s = −23.09 mm; φ = 105°, −15°, −135°.
  [[nodiscard]] static DeltaGeometry novint_falcon() noexcept;
};

/// How the device frame's axes sit on the model's.
enum class DeltaAxes : std::uint8_t {
  kModel,  ///< the model's own: z along the legs' axis, from the motors toward the grip (libnifalcon's frame)
  kZUp,    ///< turned so that z is up: device (x, y, z) = model (x, −z, y). For the Falcon on a desk:
           ///< x to the user's right, y away from the user, z up
};

/// What is wrong with a geometry, or nullptr when nothing is: a non-finite value, a or b <= 0, d or
/// e < 0, two leg angles within 1° of each other (the legs would coincide), no point of the z axis
/// reachable (|f − s| >= b, or the thighs too short to reach it), or a mechanism singular at its
/// centre. Configure time.
[[nodiscard]] const char* delta_geometry_problem(const DeltaGeometry& g) noexcept;

/// The outcome of one forward solve.
struct DeltaSolve {
  Vec3 position{};       ///< m, device frame: the solution, or the best iterate when not converged
  double residual = 0;   ///< m, largest |h_i| at position (0 at an exact solution)
  int iterations = 0;    ///< Newton steps taken
  bool converged = false;  ///< residual <= DeltaArm::kTolerance
};

class DeltaArm {
 public:
  static constexpr int kJoints = 3;
  /// Newton stops once every leg's distance to its torus is at most this (m).
  static constexpr double kTolerance = 1e-13;
  /// Newton steps at most (the Falcon's workspace needs 1 to 5).
  static constexpr int kMaxIterations = 24;

  DeltaArm() = default;
  /// `g` must pass delta_geometry_problem (that its legs reach their axis is asserted);
  /// base_offset (m) is the model origin in the device frame, whose axes sit on the model's as
  /// `axes` says: device point = A · model point + base_offset.
  explicit DeltaArm(const DeltaGeometry& g, Vec3 base_offset = {}, DeltaAxes axes = DeltaAxes::kModel) noexcept;

  [[nodiscard]] static constexpr int joint_count() noexcept { return kJoints; }
  [[nodiscard]] const DeltaGeometry& geometry() const noexcept { return g_; }
  [[nodiscard]] Vec3 base_offset() const noexcept { return base_offset_; }
  [[nodiscard]] DeltaAxes axes() const noexcept { return axes_; }
  /// m, device frame: the middle of the workspace along the legs' axis (halfway between where the
  /// thighs fold and where they stretch, in closed form), where forward solves start.
  [[nodiscard]] Vec3 centre() const noexcept { return to_device(centre_); }

  /// Forward kinematics with its diagnostics: damped Newton on the three torus distances, at most
  /// kMaxIterations steps, from the first-order prediction centre() + J_c (q − q_c) (J_c, q_c: the
  /// Jacobian and the joints at the centre): a start that depends on q alone, never on an earlier
  /// call. Where q has no solution (the legs cannot be assembled) or Newton stalls (far outside the
  /// workspace, where the shins turn coplanar), `converged` is false and `position` is the iterate
  /// with the smallest residual (centre() when q is not finite). Real-time safe.
  [[nodiscard]] DeltaSolve solve(std::span<const double> q) const noexcept;
  /// solve(q).position. Real-time safe.
  [[nodiscard]] Vec3 position(std::span<const double> q) const noexcept;
  /// The tool point with the identity orientation (the effector does not turn). Real-time safe.
  [[nodiscard]] Pose forward(std::span<const double> q) const noexcept;
  /// dp/dq, 3 × 3, closed form at solve(q).position by implicit differentiation of h(p, q) = 0:
  /// dp/dq = −(∂h/∂p)⁻¹ diag(∂h_i/∂q_i). Zero columns where ∂h/∂p is singular. Real-time safe.
  [[nodiscard]] Jacobian jacobian(std::span<const double> q) const noexcept;
  /// The Jacobian at a known tool point p (m, device frame) for joints q, without solving again
  /// (p = position(q)). Real-time safe.
  [[nodiscard]] Jacobian jacobian_at(std::span<const double> q, Vec3 p) const noexcept;
  /// The thigh angles (rad, in (−π, π]) that put the tool point at p (m, device frame), closed form
  /// (libnifalcon's root of the tan-half-angle quadratic, the knee outside); nullopt outside the
  /// reachable set. The mirror image of the workspace behind the motors (z < 0 in the model frame)
  /// solves too, though no real arm gets there. Real-time safe.
  [[nodiscard]] std::optional<std::array<double, 3>> inverse(Vec3 p) const noexcept;
  /// The 2-norm condition number of jacobian(q) (>= 1; +inf at a singularity or where the forward
  /// solve does not converge): how far q is from losing a direction of motion or of force.
  /// Real-time safe.
  [[nodiscard]] double condition_number(std::span<const double> q) const noexcept;

 private:
  /// A model-frame direction in the device frame's axes, and a model point in the device frame.
  [[nodiscard]] Vec3 turn(Vec3 v) const noexcept { return axes_ == DeltaAxes::kZUp ? Vec3{v.x, -v.z, v.y} : v; }
  [[nodiscard]] Vec3 to_device(Vec3 m) const noexcept { return turn(m) + base_offset_; }
  [[nodiscard]] Vec3 to_model(Vec3 d) const noexcept {
    const Vec3 v = d - base_offset_;
    return axes_ == DeltaAxes::kZUp ? Vec3{v.x, v.z, -v.y} : v;
  }
  /// dp/dq in the model frame at model point m.
  [[nodiscard]] Jacobian model_jacobian(std::span<const double> q, Vec3 m) const noexcept;

  DeltaGeometry g_{};
  Vec3 base_offset_{};
  DeltaAxes axes_ = DeltaAxes::kModel;
  Vec3 centre_{};                          // model frame
  double centre_joint_ = 0;                // rad, every thigh's angle at the centre
  std::array<Vec3, 3> centre_jacobian_{};  // dp/dq at the centre
  std::array<double, 3> cos_phi_{}, sin_phi_{};
};

/// The 2-norm condition number of the first three columns of j (σ_max / σ_min; +inf when
/// singular). Real-time safe.
[[nodiscard]] double condition_number(const Jacobian& j) noexcept;

}  // namespace lancet::arm
