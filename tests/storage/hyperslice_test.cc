#include "storage/hyperslice.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace hvdb {
namespace {

double Dot(const std::array<double, 4>& a, const std::array<double, 4>& b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3];
}

TEST(HypersliceTest, FrameIsOrthonormal) {
  std::mt19937_64 rng(3);
  std::normal_distribution<double> n(0, 1);
  for (int i = 0; i < 200; ++i) {
    Slice s;
    s.normal = {n(rng), n(rng), n(rng), n(rng)};
    auto g = SliceGeometry::Make(s, 1.0);
    ASSERT_TRUE(g.ok());
    std::array<std::array<double, 4>, 4> v = {g->normal(), g->basis()[0], g->basis()[1],
                                              g->basis()[2]};
    for (int a = 0; a < 4; ++a) {
      for (int b = 0; b < 4; ++b) EXPECT_NEAR(Dot(v[a], v[b]), a == b ? 1 : 0, 1e-12);
    }
  }
}

TEST(HypersliceTest, SliceOrthogonalToTimeIsTheFrame) {
  Slice s;
  s.normal = {0, 0, 0, 1};
  s.offset = 2.0;
  s.thickness = 0.01;
  auto g = SliceGeometry::Make(s, 1.0);
  ASSERT_TRUE(g.ok());
  Point p;
  p.x = 1;
  p.y = 2;
  p.z = 3;
  p.cov = {1, 0.5f, 0.25f, 2, 0.125f, 3};
  EXPECT_TRUE(g->Selects(p.x, p.y, p.z, 2.0));
  EXPECT_FALSE(g->Selects(p.x, p.y, p.z, 2.1));
  Point q = p;
  g->Project(&q, 2.0, 1 / 30.0);
  EXPECT_FLOAT_EQ(q.x, 1);
  EXPECT_FLOAT_EQ(q.y, 2);
  EXPECT_FLOAT_EQ(q.z, 3);
  for (int i = 0; i < 6; ++i) EXPECT_FLOAT_EQ(q.cov[i], p.cov[i]);  // dt drops out
}

TEST(HypersliceTest, SliceAlongXShowsTime) {
  // N = e_x: the slice x = 1 over all t projects to (y, z, s t); time extent shows up in cov.
  Slice s;
  s.normal = {1, 0, 0, 0};
  s.offset = 1.0;
  s.thickness = 0.1;
  const double scale = 2.0, dt = 0.5;
  auto g = SliceGeometry::Make(s, scale);
  ASSERT_TRUE(g.ok());
  Point p;
  p.x = 1.05f;
  p.y = 2;
  p.z = 3;
  p.cov = {1, 0, 0, 4, 0, 9};
  ASSERT_TRUE(g->Selects(p.x, p.y, p.z, 7.0));
  g->Project(&p, 7.0, dt);
  EXPECT_FLOAT_EQ(p.x, 2);
  EXPECT_FLOAT_EQ(p.y, 3);
  EXPECT_FLOAT_EQ(p.z, 14);  // s t
  EXPECT_FLOAT_EQ(p.cov[0], 4);
  EXPECT_FLOAT_EQ(p.cov[3], 9);
  EXPECT_FLOAT_EQ(p.cov[5], float(scale * dt * scale * dt));
}

TEST(HypersliceTest, CovarianceProjectionIsEq83) {
  // Compare with the explicit product P R V R^T P^T for a tilted slice.
  Slice s;
  s.normal = {0.3, -0.2, 0.5, 0.8};
  auto g = SliceGeometry::Make(s, 1.5);
  ASSERT_TRUE(g.ok());
  Point p;
  p.cov = {0.5f, 0.1f, 0.0f, 0.7f, -0.2f, 0.9f};
  const double dt = 0.04, st = 1.5 * dt;
  double V[4][4] = {{0.5, 0.1, 0, 0}, {0.1, 0.7, -0.2, 0}, {0, -0.2, 0.9, 0}, {0, 0, 0, st * st}};
  Point q = p;
  g->Project(&q, 0.0, dt);
  const auto& B = g->basis();
  double want[3][3] = {};
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j) want[r][c] += B[r][i] * V[i][j] * B[c][j];
  EXPECT_NEAR(q.cov[0], want[0][0], 1e-6);
  EXPECT_NEAR(q.cov[1], want[0][1], 1e-6);
  EXPECT_NEAR(q.cov[2], want[0][2], 1e-6);
  EXPECT_NEAR(q.cov[3], want[1][1], 1e-6);
  EXPECT_NEAR(q.cov[4], want[1][2], 1e-6);
  EXPECT_NEAR(q.cov[5], want[2][2], 1e-6);
}

TEST(HypersliceTest, ClassifyAgreesWithPointTests) {
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<float> u(-1, 1);
  Slice s;
  s.normal = {0.6, 0.0, 0.0, 0.8};
  s.offset = 0.1;
  s.thickness = 0.2;
  auto g = SliceGeometry::Make(s, 1.0);
  ASSERT_TRUE(g.ok());
  for (int i = 0; i < 2000; ++i) {
    Box3 b;
    for (int a = 0; a < 3; ++a) {
      float x = u(rng), y = u(rng);
      b.lo[a] = std::min(x, y);
      b.hi[a] = std::max(x, y);
    }
    double t = u(rng);
    Relation r = g->Classify(b, t);
    int in = 0, total = 0;
    for (int k = 0; k < 8; ++k, ++total) {
      float c[3] = {(k & 1) ? b.hi[0] : b.lo[0], (k & 2) ? b.hi[1] : b.lo[1],
                    (k & 4) ? b.hi[2] : b.lo[2]};
      in += g->Selects(c[0], c[1], c[2], t);
    }
    if (r == Relation::kInside) {
      EXPECT_EQ(in, total);
    }
    if (r == Relation::kOutside) {
      EXPECT_EQ(in, 0);
    }
  }
}

TEST(HypersliceTest, TimeRange) {
  Slice s;
  s.normal = {1, 0, 0, 1};  // x + t = b
  s.offset = 5;
  s.thickness = 0;
  auto g = SliceGeometry::Make(s, 1.0);
  ASSERT_TRUE(g.ok());
  Box3 b{{0, 0, 0}, {1, 1, 1}};
  auto [t0, t1] = g->TimeRange(b);
  EXPECT_NEAR(t0, 4, 1e-9);
  EXPECT_NEAR(t1, 5, 1e-9);
}

TEST(HypersliceTest, RejectsBadParameters) {
  Slice s;
  s.normal = {0, 0, 0, 0};
  EXPECT_TRUE(SliceGeometry::Make(s, 1).status().IsInvalidArgument());
  s.normal = {0, 0, 0, NAN};
  EXPECT_TRUE(SliceGeometry::Make(s, 1).status().IsInvalidArgument());
  s.normal = {0, 0, 0, 1};
  s.thickness = -1;
  EXPECT_TRUE(SliceGeometry::Make(s, 1).status().IsInvalidArgument());
  s.thickness = 0;
  s.offset = INFINITY;
  EXPECT_TRUE(SliceGeometry::Make(s, 1).status().IsInvalidArgument());
  Window w;
  w.lo = {1, 0, 0, 0};
  w.hi = {0, 1, 1, 1};
  EXPECT_TRUE(ValidateWindow(w).IsInvalidArgument());
}

}  // namespace
}  // namespace hvdb
