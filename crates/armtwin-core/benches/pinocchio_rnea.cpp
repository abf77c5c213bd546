// Pinocchio's C++ `rnea` on the arm and state of `benches/dynamics.rs` (UR10e, 5 kg payload, rotor
// inertia as armature), timed exactly as `examples/dynamics_min_time.rs` times armtwin's: 3 000
// rounds of 200 calls, per-call time of each round, reporting the fastest round and the median.
// Prints the torques so that they can be compared with armtwin's for the same state; the figures
// are in README.md beside this file ("Inverse dynamics").

/* Build from the workspace root with the headers and libpinocchio of the test venv's `pin` wheel
   (tests/run_all.sh), Eigen 3.4 headers from PyPI's cmeel-eigen and g++ 12; the defines are those
   of pinocchio's CMake targets. Two builds: header-only (the templates compiled here), and linked
   to the wheel's own build (what `pin.rnea` runs).

pip install --target .cache/cmeel-eigen "cmeel-eigen<4"
P=.venv/lib/python3.11/site-packages/cmeel.prefix
E=.cache/cmeel-eigen/cmeel.prefix/include/eigen3
DEFS="-DBOOST_MPL_LIMIT_LIST_SIZE=30 -DBOOST_MPL_LIMIT_VECTOR_SIZE=30 -DBOOST_MPL_CFG_NO_PREPROCESSED_HEADERS -DBOOST_FUSION_INVOKE_MAX_ARITY=12"
g++ -O3 -DNDEBUG -std=c++17 $DEFS -I$E -I$P/include \
  crates/armtwin-core/benches/pinocchio_rnea.cpp -o target/pinocchio_rnea_header_only
g++ -O3 -DNDEBUG -std=c++17 $DEFS -DPINOCCHIO_ENABLE_TEMPLATE_INSTANTIATION -I$E -I$P/include \
  crates/armtwin-core/benches/pinocchio_rnea.cpp -o target/pinocchio_rnea_linked \
  -L$P/lib -lpinocchio_default -Wl,-rpath,$P/lib
target/pinocchio_rnea_header_only && target/pinocchio_rnea_linked
*/
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <vector>

#include <pinocchio/multibody.hpp>
#include <pinocchio/algorithm/rnea.hpp>

namespace pin = pinocchio;

static pin::SE3 tz_tx_rx(double d, double a, double alpha) {
  Eigen::Matrix3d rx;
  const double c = std::abs(alpha) == M_PI / 2 ? 0.0 : std::cos(alpha);
  const double s = std::abs(alpha) == M_PI / 2 ? std::copysign(1.0, alpha) : std::sin(alpha);
  rx << 1, 0, 0, 0, c, -s, 0, s, c;
  return pin::SE3(rx, Eigen::Vector3d(a, 0, d));
}

int main() {
  // UR10e: DH (d, a, alpha) per row, masses, centres of mass and diagonal inertias (DH link frames).
  const double d[6] = {0.1807, 0, 0, 0.17415, 0.11985, 0.11655};
  const double a[6] = {0, -0.6127, -0.57155, 0, 0, 0};
  const double alpha[6] = {M_PI / 2, 0, 0, M_PI / 2, -M_PI / 2, 0};
  const double mass[6] = {7.369, 13.051, 3.989, 2.10, 1.98, 0.615};
  const double com[6][3] = {{0.021, 0, 0.027}, {0.38, 0, 0.158}, {0.24, 0, 0.068},
                            {0, 0.007, 0.018}, {0, 0.007, 0.018}, {0, 0, -0.026}};
  const double inertia[6][3] = {{0.03408, 0.03529, 0.02156}, {0.02814, 0.77068, 0.76943},
                                {0.01014, 0.30928, 0.30646}, {0.00296, 0.00222, 0.00258},
                                {0.00296, 0.00222, 0.00258}, {0.00040, 0.00041, 0.00034}};
  const double rotor[6] = {5.90109e-4, 5.90109e-4, 1.8774e-4, 6.0e-5, 6.0e-5, 6.0e-5};

  pin::Model model;
  pin::JointIndex parent = 0;
  for (int k = 0; k < 6; ++k) {
    const pin::SE3 placement = k == 0 ? pin::SE3::Identity() : tz_tx_rx(d[k - 1], a[k - 1], alpha[k - 1]);
    parent = model.addJoint(parent, pin::JointModelRZ(), placement, "joint" + std::to_string(k + 1));
    const pin::Inertia link(mass[k], Eigen::Vector3d(com[k][0], com[k][1], com[k][2]),
                            Eigen::Vector3d(inertia[k][0], inertia[k][1], inertia[k][2]).asDiagonal());
    model.appendBodyToJoint(parent, tz_tx_rx(d[k], a[k], alpha[k]).act(link), pin::SE3::Identity());
    model.armature[k] = rotor[k] * 101.0 * 101.0;
  }
  const pin::SE3 flange = tz_tx_rx(d[5], a[5], alpha[5]);
  model.appendBodyToJoint(parent, pin::Inertia(5.0, Eigen::Vector3d::Zero(), Eigen::Matrix3d::Zero()),
                          flange * pin::SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.01, 0, 0.08)));
  model.gravity.linear(Eigen::Vector3d(0, 0, -9.82));
  pin::Data data(model);

  Eigen::VectorXd q(6), qd(6), qdd(6);
  q << 0.31, -1.22, 1.43, -0.87, 1.52, 0.64;
  qd << 0.4, -0.3, 0.5, 0.8, -0.6, 1.1;
  qdd << 1.5, -2.0, 2.5, 3.0, -1.0, 4.0;

  const int rounds = 3000, calls = 200;
  std::vector<double> per_call_ns;
  per_call_ns.reserve(rounds);
  double sink = 0;
  for (int r = 0; r < rounds; ++r) {
    const auto start = std::chrono::steady_clock::now();
    for (int c = 0; c < calls; ++c) {
      q[0] += 1e-12;  // a fresh state each call, as the compiler cannot hoist it
      sink += pin::rnea(model, data, q, qd, qdd)[1];
    }
    const auto stop = std::chrono::steady_clock::now();
    per_call_ns.push_back(std::chrono::duration<double, std::nano>(stop - start).count() / calls);
  }
  std::sort(per_call_ns.begin(), per_call_ns.end());
  q[0] = 0.31;
  const Eigen::VectorXd tau = pin::rnea(model, data, q, qd, qdd);
  std::printf("pinocchio rnea/ur10e: fastest round %.1f ns, median %.1f ns per call (sink %g)\n",
              per_call_ns.front(), per_call_ns[rounds / 2], sink);
  std::printf("tau_nm = [%.17g, %.17g, %.17g, %.17g, %.17g, %.17g]\n", tau[0], tau[1], tau[2], tau[3], tau[4],
              tau[5]);
  return 0;
}
