// The bounded renderer pool behind the server's render service.
#include "render/renderer_pool.h"

#include <gtest/gtest.h>

#include <cstdlib>

namespace hvdb::render {
namespace {

TEST(RendererPoolTest, BoundsConcurrentRendersAndReusesRenderers) {
  RendererPool pool(2);
  auto a = pool.TryAcquire(RendererKind::kCpu);
  auto b = pool.TryAcquire(RendererKind::kCpu);
  ASSERT_TRUE(a.ok());
  ASSERT_TRUE(b.ok());
  auto c = pool.TryAcquire(RendererKind::kCpu);
  EXPECT_EQ(c.status().code(), StatusCode::kOverloaded);
  EXPECT_EQ(pool.in_use(), 2u);
  auto ra = a->Get();
  ASSERT_TRUE(ra.ok());
  Renderer* first = *ra;
  EXPECT_EQ(first->kind(), RendererKind::kCpu);
  { auto gone = std::move(a).value(); }  // the lease ends: slot and renderer come back
  EXPECT_EQ(pool.in_use(), 1u);
  auto d = pool.TryAcquire(RendererKind::kCpu);
  ASSERT_TRUE(d.ok());
  auto rd = d->Get();
  ASSERT_TRUE(rd.ok());
  EXPECT_EQ(*rd, first);  // the idle renderer is reused
  EXPECT_FALSE(d->fallback());
}

TEST(RendererPoolTest, AutoFallsBackOnceEglFails) {
  ::setenv("HVDB_RENDER_NO_EGL", "1", 1);
  std::vector<std::string> warnings;
  SetLogHandler([&](const std::string& m) { warnings.push_back(m); });
  RendererPool pool(1);
  for (int i = 0; i < 2; ++i) {
    auto lease = pool.TryAcquire(RendererKind::kAuto);
    ASSERT_TRUE(lease.ok());
    auto r = lease->Get();
    ASSERT_TRUE(r.ok());
    EXPECT_EQ((*r)->kind(), RendererKind::kCpu);
    EXPECT_TRUE(lease->fallback());
  }
  auto strict = pool.TryAcquire(RendererKind::kEgl);
  ASSERT_TRUE(strict.ok());
  EXPECT_EQ(strict->Get().status().code(), StatusCode::kUnsupported);
  ::unsetenv("HVDB_RENDER_NO_EGL");
  SetLogHandler(nullptr);
  EXPECT_EQ(warnings.size(), 1u);  // said once, not per request
}

TEST(RendererPoolTest, AutoChoosesOncePerPoolAndSaysWhy) {
  auto egl = MakeEglRenderer();
  const bool gpu = egl.ok() && (*egl)->hardware();
  egl = Status::Unsupported("released");
  SetLogHandler([](const std::string&) {});
  RendererPool pool(1);
  for (int i = 0; i < 2; ++i) {
    auto lease = pool.TryAcquire(RendererKind::kAuto);
    ASSERT_TRUE(lease.ok());
    auto r = lease->Get();
    ASSERT_TRUE(r.ok());
    EXPECT_EQ((*r)->kind(), gpu ? RendererKind::kEgl : RendererKind::kCpu);
    EXPECT_EQ(lease->why().rfind("render service: ", 0), 0u) << lease->why();
  }
  auto cpu = pool.TryAcquire(RendererKind::kCpu);
  ASSERT_TRUE(cpu.ok());
  ASSERT_TRUE(cpu->Get().ok());
  EXPECT_EQ(cpu->why(), "asked for the CPU renderer");
  SetLogHandler(nullptr);
}

}  // namespace
}  // namespace hvdb::render
