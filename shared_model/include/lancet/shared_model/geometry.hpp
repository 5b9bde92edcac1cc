#pragma once
// Plain geometric value types that cross the process boundary. All trivially copyable and
// standard-layout; positions in metres, the frame is the world frame of the tissue unless a
// field's comment says otherwise.

#include <cmath>
#include <type_traits>

namespace lancet {

/// 3-vector of doubles (metres, newtons or unit directions, as the field says).
struct Vec3 {
  double x{0}, y{0}, z{0};

  friend constexpr Vec3 operator+(Vec3 a, Vec3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
  friend constexpr Vec3 operator-(Vec3 a, Vec3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
  friend constexpr Vec3 operator-(Vec3 a) { return {-a.x, -a.y, -a.z}; }
  friend constexpr Vec3 operator*(double s, Vec3 a) { return {s * a.x, s * a.y, s * a.z}; }
  friend constexpr Vec3 operator*(Vec3 a, double s) { return s * a; }
  friend constexpr bool operator==(Vec3 a, Vec3 b) = default;
  constexpr Vec3& operator+=(Vec3 b) { return *this = *this + b; }
  constexpr Vec3& operator-=(Vec3 b) { return *this = *this - b; }
};

constexpr double dot(Vec3 a, Vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
constexpr Vec3 cross(Vec3 a, Vec3 b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline double norm(Vec3 a) { return std::sqrt(dot(a, a)); }
/// Unit vector along a; returns the zero vector when |a| is below 1e-300 (never NaN).
inline Vec3 normalized(Vec3 a) {
  const double n = norm(a);
  return n > 1e-300 ? (1.0 / n) * a : Vec3{};
}
inline bool is_finite(Vec3 a) { return std::isfinite(a.x) && std::isfinite(a.y) && std::isfinite(a.z); }

/// 3-vector of floats: compact vertex storage in TissuePatch (metres).
struct Vec3f {
  float x{0}, y{0}, z{0};
  friend constexpr bool operator==(Vec3f a, Vec3f b) = default;
};
constexpr Vec3 to_vec3(Vec3f v) { return {v.x, v.y, v.z}; }
constexpr Vec3f to_vec3f(Vec3 v) {
  return {static_cast<float>(v.x), static_cast<float>(v.y), static_cast<float>(v.z)};
}

/// Unit quaternion (w, x, y, z), Hamilton convention, rotating body-frame vectors to world.
struct Quat {
  double w{1}, x{0}, y{0}, z{0};
  friend constexpr bool operator==(Quat a, Quat b) = default;
};

/// Rotates v by the unit quaternion q.
constexpr Vec3 rotate(Quat q, Vec3 v) {
  const Vec3 u{q.x, q.y, q.z};
  const Vec3 t = 2.0 * cross(u, v);
  return v + q.w * t + cross(u, t);
}

/// Rigid pose: position (m) and orientation of a body frame in the world frame.
struct Pose {
  Vec3 position;
  Quat orientation;
  friend constexpr bool operator==(const Pose&, const Pose&) = default;
};

static_assert(std::is_trivially_copyable_v<Vec3> && std::is_standard_layout_v<Vec3>);
static_assert(std::is_trivially_copyable_v<Vec3f> && std::is_standard_layout_v<Vec3f>);
static_assert(std::is_trivially_copyable_v<Pose> && std::is_standard_layout_v<Pose>);

}  // namespace lancet
