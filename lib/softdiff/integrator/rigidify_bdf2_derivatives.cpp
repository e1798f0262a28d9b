// Derivatives of the BDF2 extrapolation of rigidified parts: see rigidify_bdf2_derivatives.hpp.
#include <softdiff/integrator/rigidify_bdf2_derivatives.hpp>

#include <softdiff/data.hpp>
#include <softdiff/integrator/rigidify.hpp>
#include <softdiff/model.hpp>
#include <softdiff/rigid/rotation.hpp>

#include <Eigen/SVD>

namespace softdiff::integrator {

namespace {
constexpr double kNew = 4.0 / 3.0, kOld = 1.0 / 3.0;

// The part's extrapolation at (in, previous), as rigidify_extrapolated_state computes it,
// with the linearization's matrices.
struct Extrapolation {
  Vec3 c = Vec3::Zero(), c_prev = Vec3::Zero(), c_hat = Vec3::Zero();
  double m = 0;
  Mat3 R, E;
  Mat3 Sop_inv;  // (tr S I - S)^{-1}
  Mat3 Q;        // theta = Q w: J_r(phi / 3) J_r(phi)^{-1} / 3
  Mat3 I_inv;    // I^{-1} at x^
  Vec3 omega = Vec3::Zero();  // omega^
};

Extrapolation extrapolation(const Model& model, const RigidifiedPart& part, const State& in, const State& previous) {
  Extrapolation e;
  const VecX &x = in.x, &xp = previous.x;
  e.c = part_centre(model, part, x);
  e.c_prev = part_centre(model, part, xp);
  e.c_hat = kNew * e.c - kOld * e.c_prev;
  Mat3 H = Mat3::Zero();  // sum m b a^T, as rigidify_extrapolated_state
  for (int i : part.nodes) {
    const double mi = model.fem.mass_diagonal[3 * i];
    e.m += mi;
    H.noalias() += mi * (xp.segment<3>(3 * i) - e.c_prev) * (x.segment<3>(3 * i) - e.c).transpose();
  }
  const Eigen::JacobiSVD<Mat3> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Mat3 D = Mat3::Identity();
  D(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0 ? -1 : 1;
  e.R = svd.matrixV() * D * svd.matrixU().transpose();
  const Eigen::AngleAxisd aa(e.R);
  e.E = Eigen::AngleAxisd(aa.angle() / 3, aa.axis()).toRotationMatrix();
  const Vec3 phi = aa.angle() * aa.axis();
  // K = H^T = R S.
  const Mat3 RK = e.R.transpose() * H.transpose();
  const Mat3 S = 0.5 * (RK + RK.transpose());
  e.Sop_inv = (S.trace() * Mat3::Identity() - S).inverse();
  e.Q = rigid::right_jacobian(phi / 3) * rigid::right_jacobian(phi).inverse() / 3;
  Mat3 I = Mat3::Zero();
  Vec3 L = Vec3::Zero();
  for (int i : part.nodes) {
    const double mi = model.fem.mass_diagonal[3 * i];
    const Vec3 a = x.segment<3>(3 * i) - e.c, b = xp.segment<3>(3 * i) - e.c_prev, r = e.E * a;
    L += mi * (kNew * a.cross(Vec3(in.v.segment<3>(3 * i))) - kOld * b.cross(Vec3(previous.v.segment<3>(3 * i))));
    I += mi * (r.squaredNorm() * Mat3::Identity() - r * r.transpose());
  }
  e.I_inv = I.inverse();
  e.omega = e.I_inv * L;
  return e;
}

Vec3 row(const VecX& v, int i) { return v.size() ? Vec3(v.segment<3>(3 * i)) : Vec3::Zero(); }
}  // namespace

void rigidify_extrapolation_jvp(const Model& model, const State& in, const State& previous, const VecX& dx_n,
                                const VecX& dv_n, const VecX& dx_prev, const VecX& dv_prev, VecX& dx_hat,
                                VecX& dv_hat) {
  for (const auto& part : model.rigidify.parts) {
    const Extrapolation e = extrapolation(model, part, in, previous);
    Vec3 dc = Vec3::Zero(), dc_prev = Vec3::Zero(), dp = Vec3::Zero(), g = Vec3::Zero();
    for (int i : part.nodes) {
      const double mi = model.fem.mass_diagonal[3 * i];
      dc += mi * row(dx_n, i);
      dc_prev += mi * row(dx_prev, i);
      dp += mi * (kNew * row(dv_n, i) - kOld * row(dv_prev, i));
      const Vec3 a = in.x.segment<3>(3 * i) - e.c, b = previous.x.segment<3>(3 * i) - e.c_prev;
      g += mi * (b.cross(Vec3(e.R.transpose() * row(dx_n, i))) - Vec3(e.R.transpose() * a).cross(row(dx_prev, i)));
    }
    dc /= e.m;
    dc_prev /= e.m;
    const Vec3 dv_p = dp / e.m, dc_hat = kNew * dc - kOld * dc_prev;
    const Vec3 theta = e.Q * (e.Sop_inv * g);
    // dL and dI^ omega^.
    Vec3 dL = Vec3::Zero(), dI_omega = Vec3::Zero();
    for (int i : part.nodes) {
      const double mi = model.fem.mass_diagonal[3 * i];
      const Vec3 a = in.x.segment<3>(3 * i) - e.c, b = previous.x.segment<3>(3 * i) - e.c_prev, r = e.E * a;
      const Vec3 da = row(dx_n, i) - dc, db = row(dx_prev, i) - dc_prev;
      const Vec3 dr = e.E * (theta.cross(a) + da);
      const Vec3 vn = in.v.segment<3>(3 * i), vp = previous.v.segment<3>(3 * i);
      dL += mi * (kNew * (da.cross(vn) + a.cross(row(dv_n, i))) - kOld * (db.cross(vp) + b.cross(row(dv_prev, i))));
      // dI q = sum m (2 r.dr q - dr (r.q) - r (dr.q))
      dI_omega += mi * (2 * r.dot(dr) * e.omega - dr * r.dot(e.omega) - r * dr.dot(e.omega));
      dx_hat.segment<3>(3 * i) = dc_hat + dr;
    }
    const Vec3 domega = e.I_inv * (dL - dI_omega);
    for (int i : part.nodes) {
      const Vec3 a = in.x.segment<3>(3 * i) - e.c, r = e.E * a;
      const Vec3 dr = dx_hat.segment<3>(3 * i) - dc_hat;
      dv_hat.segment<3>(3 * i) = dv_p + domega.cross(r) + e.omega.cross(dr);
    }
  }
}

void rigidify_extrapolation_vjp(const Model& model, const State& in, const State& previous, const VecX& bar_x_hat,
                                const VecX& bar_v_hat, VecX& bar_x_n, VecX& bar_v_n, VecX& bar_x_prev,
                                VecX& bar_v_prev) {
  for (const auto& part : model.rigidify.parts) {
    const Extrapolation e = extrapolation(model, part, in, previous);
    // v^_i = v_p^ + omega^ x r_i, x^_i = c^ + r_i.
    Vec3 bar_vp = Vec3::Zero(), bar_omega = Vec3::Zero(), bar_c_hat = Vec3::Zero();
    for (int i : part.nodes) {
      const Vec3 r = e.E * (in.x.segment<3>(3 * i) - e.c), bv = row(bar_v_hat, i);
      bar_vp += bv;
      bar_omega += r.cross(bv);
      bar_c_hat += row(bar_x_hat, i);
    }
    const Vec3 gamma = e.I_inv.transpose() * bar_omega;  // omega^ = I^{-1} L: bar_L = gamma
    const Vec3& bar_L = gamma;
    // bar_r_i, then through dr_i = E (theta x a_i + da_i): bar_theta and bar_a_i (kept in
    // bar_x_n's rows until the arms' transpose below).
    Vec3 bar_theta = Vec3::Zero(), sum_bar_a = Vec3::Zero(), sum_bar_b = Vec3::Zero();
    for (int i : part.nodes) {
      const double mi = model.fem.mass_diagonal[3 * i];
      const Vec3 a = in.x.segment<3>(3 * i) - e.c, b = previous.x.segment<3>(3 * i) - e.c_prev, r = e.E * a;
      Vec3 bar_r = row(bar_x_hat, i) + row(bar_v_hat, i).cross(e.omega);
      bar_r -= mi * (2 * gamma.dot(e.omega) * r - r.dot(e.omega) * gamma - r.dot(gamma) * e.omega);  // -gamma^T dI omega
      const Vec3 ei = e.E.transpose() * bar_r;
      bar_theta += a.cross(ei);
      const Vec3 vn = in.v.segment<3>(3 * i), vp = previous.v.segment<3>(3 * i);
      const Vec3 bar_a = ei + kNew * mi * vn.cross(bar_L);
      const Vec3 bar_b = -kOld * mi * vp.cross(bar_L);
      bar_x_n.segment<3>(3 * i) = bar_a;
      bar_x_prev.segment<3>(3 * i) = bar_b;
      sum_bar_a += bar_a;
      sum_bar_b += bar_b;
      bar_v_n.segment<3>(3 * i) = kNew * mi * (bar_L.cross(a) + bar_vp / e.m);
      bar_v_prev.segment<3>(3 * i) = -kOld * mi * (bar_L.cross(b) + bar_vp / e.m);
    }
    // theta = Q Sop^{-1} g.
    const Vec3 bar_g = e.Sop_inv.transpose() * (e.Q.transpose() * bar_theta);
    // The arms (a_i = x_i - c, c = sum m x / m; the same for b at x_{n-1}), c^ = 4/3 c - 1/3 c_prev,
    // and g's direct terms m R (bar_g x b_i), -m (bar_g x R^T a_i).
    const Vec3 centre = (kNew * bar_c_hat - sum_bar_a) / e.m, centre_prev = (-kOld * bar_c_hat - sum_bar_b) / e.m;
    for (int i : part.nodes) {
      const double mi = model.fem.mass_diagonal[3 * i];
      const Vec3 a = in.x.segment<3>(3 * i) - e.c, b = previous.x.segment<3>(3 * i) - e.c_prev;
      bar_x_n.segment<3>(3 * i) += mi * centre + mi * (e.R * bar_g.cross(b));
      bar_x_prev.segment<3>(3 * i) += mi * centre_prev - mi * bar_g.cross(Vec3(e.R.transpose() * a));
    }
  }
}

}  // namespace softdiff::integrator
