// Crash safety with real process death.
//
// A forked child opens the database and runs a deterministic workload (bulk loads, and
// transactions of inserts, deletes by id and by window, label edits and transforms) derived
// from a seed. After every operation that returned OK it writes an acknowledgement to a pipe
// before starting the next one. The parent SIGKILLs it at a random (seeded) moment, reopens
// the directory and compares the recovered dataset with an in-process model of the same
// workload: with k operations acknowledged, the durable state must be exactly the model after
// k operations or after k + 1 (the last one may have become durable without being
// acknowledged). Any other state means a lost acknowledged commit or a torn transaction.
//
// SIGKILL keeps the kernel's page cache, so these tests cover the engine's ordering of writes,
// renames and log appends, not what an fsync would add against power loss.
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <limits>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "storage/database.h"
#include "storage/point.h"
#include "storage/status.h"

namespace hvdb {
namespace {

constexpr double kFps = 30.0;
constexpr uint32_t kFrameSpan = 8;  // inserts go to frames 0..7
constexpr const char* kDatasetName = "video";
constexpr int kMaxSteps = 4000;  // a child that is never killed stops here

// ------------------------------------------------------------------------------------------
// Helpers

class TempDir {
 public:
  TempDir() {
    char tmpl[] = "/tmp/hvdb_crash_XXXXXX";
    const char* p = ::mkdtemp(tmpl);
    if (p == nullptr) std::abort();
    path_ = p;
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

Options CrashOptions(bool sync, bool small_log) {
  Options o;
  o.cache_bytes = 8u << 20;
  o.block_size = 4096;
  o.t0_points = 64;  // merges are frequent
  o.sync = sync;
  if (small_log) o.wal_checkpoint_bytes = 128u << 10;  // checkpoints and log segments too
  return o;
}

Window Everything() {
  const double inf = std::numeric_limits<double>::infinity();
  Window w;
  w.lo = {-inf, -inf, -inf, -inf};
  w.hi = {inf, inf, inf, inf};
  return w;
}

using Key = std::pair<uint32_t, uint64_t>;  // (frame, id)
using PointMap = std::map<Key, Point>;

std::string Describe(const Point& p) {
  char buf[200];
  std::snprintf(buf, sizeof(buf), "frame %u id %llu (%g, %g, %g) label %#x", p.frame,
                static_cast<unsigned long long>(p.id), static_cast<double>(p.x),
                static_cast<double>(p.y), static_cast<double>(p.z), p.label);
  return buf;
}

// Reads a query to exhaustion. Duplicates are reported through `dups`.
Status Collect(Dataset& ds, const Region& region, const QueryOptions& qo, PointMap* out,
               std::vector<Point>* dups) {
  auto cur = ds.Query(region, qo);
  if (!cur.ok()) return cur.status();
  Batch batch;
  for (;;) {
    auto more = (*cur)->Next(&batch);
    if (!more.ok()) return more.status();
    for (const Point& p : batch.points) {
      if (!out->emplace(Key{p.frame, p.id}, p).second) dups->push_back(p);
    }
    if (!*more) break;
  }
  return Status::OK();
}

// A summary of how two point sets differ (empty when equal).
std::string Diff(const PointMap& got, const PointMap& want) {
  if (got == want) return "";
  size_t missing = 0, extra = 0, changed = 0;
  std::string examples;
  int shown = 0;
  for (const auto& [k, p] : want) {
    auto it = got.find(k);
    if (it == got.end()) {
      ++missing;
      if (shown++ < 3) examples += "\n  missing " + Describe(p);
    } else if (!(it->second == p)) {
      ++changed;
      if (shown++ < 3) examples += "\n  changed " + Describe(p) + " -> " + Describe(it->second);
    }
  }
  for (const auto& [k, p] : got) {
    if (!want.count(k)) {
      ++extra;
      if (shown++ < 6) examples += "\n  extra " + Describe(p);
    }
  }
  return std::to_string(got.size()) + " points vs " + std::to_string(want.size()) +
         " expected: " + std::to_string(missing) + " missing, " + std::to_string(extra) +
         " extra, " + std::to_string(changed) + " changed" + examples;
}

bool InWindow(const Window& w, const Point& p) {
  double t = p.frame / kFps;
  return t >= w.lo[3] && t <= w.hi[3] && p.x >= w.lo[0] && p.x <= w.hi[0] && p.y >= w.lo[1] &&
         p.y <= w.hi[1] && p.z >= w.lo[2] && p.z <= w.hi[2];
}

// ------------------------------------------------------------------------------------------
// The workload and its model

struct Model {
  PointMap points;
  uint64_t next_id = 1;  // the engine assigns ids 1, 2, ... in order on a fresh dataset
  uint64_t lsn = 0;      // sequence number of the last transaction
};

struct Step {
  enum Kind : uint32_t { kBulk = 1, kTxn = 2 };
  Kind kind = kTxn;
  uint32_t frame = 0;       // kBulk
  std::vector<Point> bulk;  // kBulk (ids 0)
  Transaction txn;          // kTxn
  // What the engine must answer:
  uint64_t expect_lsn = 0;
  std::vector<uint64_t> expect_ids;  // kTxn: assigned_ids
  std::string what;
};

Point RandomPoint(std::mt19937_64& rng, uint32_t frame) {
  std::uniform_real_distribution<float> pos(-8.f, 8.f);
  std::uniform_real_distribution<float> var(1e-4f, 1e-2f);
  Point p;
  p.x = pos(rng);
  p.y = pos(rng);
  p.z = pos(rng);
  p.frame = frame;
  p.cov = {var(rng), 0.f, 0.f, var(rng), 0.f, var(rng)};
  p.flags = kFlagHasCovariance;
  if (rng() % 2 == 0) {
    std::uniform_real_distribution<float> n(-1.f, 1.f);
    p.normal_oct = EncodeNormal(n(rng), n(rng), n(rng));
    p.flags |= kFlagHasNormal;
  }
  p.label = static_cast<uint32_t>(rng() % 16);
  p.r = static_cast<uint8_t>(rng());
  p.g = static_cast<uint8_t>(rng());
  p.b = static_cast<uint8_t>(rng());
  p.camera = static_cast<uint16_t>(rng() % 4);
  return p;
}

// The engine's transform (dataset.cc, TransformOp), step for step, so the model's floats are
// bit-identical. The workload only uses matrices of 0, +-1, +-2, 0.5 and dyadic offsets, for
// which every intermediate is exact anyway.
Point TransformPoint(const Point& p, const Affine4& map) {
  const auto& A = map.a;
  double S[3][3];
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) S[r][c] = A[static_cast<size_t>(r * 4 + c)];
  }
  double det = S[0][0] * (S[1][1] * S[2][2] - S[1][2] * S[2][1]) -
               S[0][1] * (S[1][0] * S[2][2] - S[1][2] * S[2][0]) +
               S[0][2] * (S[1][0] * S[2][1] - S[1][1] * S[2][0]);
  double X[4] = {p.x, p.y, p.z, p.frame / kFps};
  double Y[4];
  for (int r = 0; r < 4; ++r) {
    Y[r] = map.c[static_cast<size_t>(r)];
    for (int c = 0; c < 4; ++c) Y[r] += A[static_cast<size_t>(r * 4 + c)] * X[c];
  }
  Point q = p;
  q.x = static_cast<float>(Y[0]);
  q.y = static_cast<float>(Y[1]);
  q.z = static_cast<float>(Y[2]);
  q.frame = static_cast<uint32_t>(std::round(Y[3] * kFps));
  const auto& cv = p.cov;
  double V[3][3] = {{cv[0], cv[1], cv[2]}, {cv[1], cv[3], cv[4]}, {cv[2], cv[4], cv[5]}};
  double SV[3][3] = {}, W[3][3] = {};
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      for (int k = 0; k < 3; ++k) SV[r][c] += S[r][k] * V[k][c];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      for (int k = 0; k < 3; ++k) W[r][c] += SV[r][k] * S[c][k];
  q.cov = {static_cast<float>(W[0][0]), static_cast<float>(W[0][1]), static_cast<float>(W[0][2]),
           static_cast<float>(W[1][1]), static_cast<float>(W[1][2]), static_cast<float>(W[2][2])};
  if (p.flags & kFlagHasNormal) {
    auto n = DecodeNormal(p.normal_oct);
    double C[3][3];
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) {
        int r1 = (r + 1) % 3, r2 = (r + 2) % 3, c1 = (c + 1) % 3, c2 = (c + 2) % 3;
        C[r][c] = S[r1][c1] * S[r2][c2] - S[r1][c2] * S[r2][c1];
      }
    }
    double m[3];
    for (int r = 0; r < 3; ++r) m[r] = C[r][0] * n[0] + C[r][1] * n[1] + C[r][2] * n[2];
    if (det < 0) {
      for (double& x : m) x = -x;
    }
    q.normal_oct =
        EncodeNormal(static_cast<float>(m[0]), static_cast<float>(m[1]), static_cast<float>(m[2]));
  }
  return q;
}

// A small random window over frames [f0, f1] (f1 - f0 <= 2) with a few metres of space.
Window RandomWindow(std::mt19937_64& rng, uint32_t max_frame) {
  std::uniform_real_distribution<double> centre(-7.0, 7.0), half(0.5, 3.0);
  Window w;
  for (int a = 0; a < 3; ++a) {
    double c = centre(rng), h = half(rng);
    w.lo[static_cast<size_t>(a)] = c - h;
    w.hi[static_cast<size_t>(a)] = c + h;
  }
  uint32_t f0 = static_cast<uint32_t>(rng() % (max_frame + 1));
  uint32_t f1 = std::min(max_frame, f0 + static_cast<uint32_t>(rng() % 3));
  w.lo[3] = (f0 - 0.25) / kFps;
  w.hi[3] = (f1 + 0.25) / kFps;
  return w;
}

std::vector<Key> Selected(const Model& m, const Window& w, uint32_t label_mask) {
  std::vector<Key> out;
  for (const auto& [k, p] : m.points) {
    if (label_mask != 0 && (p.label & label_mask) == 0) continue;
    if (InWindow(w, p)) out.push_back(k);
  }
  return out;
}

// Picks up to n distinct live points.
std::vector<Point> PickPoints(std::mt19937_64& rng, const Model& m, size_t n) {
  std::vector<Point> out;
  if (m.points.empty()) return out;
  std::vector<size_t> idx;
  for (size_t i = 0; i < n; ++i) idx.push_back(rng() % m.points.size());
  std::sort(idx.begin(), idx.end());
  idx.erase(std::unique(idx.begin(), idx.end()), idx.end());
  auto it = m.points.begin();
  size_t at = 0;
  for (size_t i : idx) {
    std::advance(it, static_cast<std::ptrdiff_t>(i - at));
    at = i;
    out.push_back(it->second);
  }
  return out;
}

// Generates the next operation from the rng and the model, and applies it to the model. The
// child and the parent's replay call this in the same order, so both see the same operations.
Step NextStep(std::mt19937_64& rng, Model* m) {
  Step s;
  if (rng() % 100 < 6) {
    s.kind = Step::kBulk;
    s.frame = static_cast<uint32_t>(rng() % kFrameSpan);
    size_t n = 200 + rng() % 2800;
    for (size_t i = 0; i < n; ++i) s.bulk.push_back(RandomPoint(rng, s.frame));
    for (Point p : s.bulk) {
      p.id = m->next_id++;
      m->points[{p.frame, p.id}] = p;
    }
    s.what = " bulk load of " + std::to_string(n) + " points into frame " + std::to_string(s.frame);
    s.expect_lsn = ++m->lsn;  // a bulk load takes an LSN of its own
    return s;
  }
  s.kind = Step::kTxn;
  int nops = 1 + static_cast<int>(rng() % 4);
  for (int op = 0; op < nops; ++op) {
    unsigned r = static_cast<unsigned>(rng() % 100);
    if (r < 40 || m->points.empty()) {
      // Insert 10..200 points over 1..3 frames.
      size_t n = 10 + rng() % 191;
      uint32_t frames[3];
      for (uint32_t& f : frames) f = static_cast<uint32_t>(rng() % kFrameSpan);
      std::vector<Point> pts;
      for (size_t i = 0; i < n; ++i) pts.push_back(RandomPoint(rng, frames[rng() % 3]));
      for (Point p : pts) {
        p.id = m->next_id++;
        s.expect_ids.push_back(p.id);
        m->points[{p.frame, p.id}] = p;
      }
      s.txn.Insert(std::move(pts));
      s.what += " insert(" + std::to_string(n) + ")";
    } else if (r < 60) {
      // Delete 1..6 points by id, frame and position.
      auto victims = PickPoints(rng, *m, 1 + rng() % 6);
      for (const Point& p : victims) {
        s.txn.Delete(p.id, p.frame, {p.x, p.y, p.z});
        m->points.erase({p.frame, p.id});
      }
      s.what += " delete(" + std::to_string(victims.size()) + ")";
    } else if (r < 70) {
      // Delete a small window, sometimes only points with some label bit.
      Window w = RandomWindow(rng, kFrameSpan + 1);
      std::uniform_real_distribution<double> half(0.3, 1.2);
      for (int a = 0; a < 3; ++a) {
        auto ua = static_cast<size_t>(a);
        double c = (w.lo[ua] + w.hi[ua]) / 2, h = half(rng);
        w.lo[ua] = c - h;
        w.hi[ua] = c + h;
      }
      uint32_t mask = rng() % 3 == 0 ? (1u << (rng() % 4)) : 0u;
      auto keys = Selected(*m, w, mask);
      for (const Key& k : keys) m->points.erase(k);
      Selection sel;
      sel.region = w;
      sel.label_mask = mask;
      s.txn.DeleteSelection(std::move(sel));
      s.what += " delete_window(" + std::to_string(keys.size()) + ")";
    } else if (r < 85) {
      // Set or clear a label bit on a window or on explicit ids.
      uint32_t bits = 1u << (rng() % 8);
      bool set = rng() % 3 != 0;
      Selection sel;
      std::vector<Key> keys;
      if (rng() % 2 == 0) {
        Window w = RandomWindow(rng, kFrameSpan + 1);
        uint32_t mask = rng() % 4 == 0 ? (1u << (rng() % 4)) : 0u;
        keys = Selected(*m, w, mask);
        sel.region = w;
        sel.label_mask = mask;
      } else {
        for (const Point& p : PickPoints(rng, *m, 1 + rng() % 20)) {
          keys.push_back({p.frame, p.id});
          sel.ids.emplace_back(p.frame, p.id);
        }
      }
      for (const Key& k : keys) {
        Point& p = m->points.at(k);
        p.label = set ? (p.label | bits) : (p.label & ~bits);
      }
      s.txn.SetLabel(std::move(sel), bits, set);
      s.what +=
          std::string(set ? " set" : " clear") + "_label(" + std::to_string(keys.size()) + ")";
    } else {
      // Transform a window: translate, rotate about z, scale, or move one frame in time.
      Window w = RandomWindow(rng, kFrameSpan + 1);
      Affine4 map;
      const char* kind = "";
      switch (rng() % 4) {
        case 0: {
          kind = "translate";
          for (size_t a = 0; a < 3; ++a) map.c[a] = static_cast<double>(rng() % 17) / 8.0 - 1.0;
          break;
        }
        case 1:
          kind = "rotate";
          map.a = {0, -1, 0, 0, 1, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
          break;
        case 2: {
          kind = "scale";
          double f = rng() % 2 == 0 ? 2.0 : 0.5;
          map.a = {f, 0, 0, 0, 0, f, 0, 0, 0, 0, -f, 0, 0, 0, 0, 1};  // also mirrors z
          break;
        }
        default: {
          kind = "shift_time";
          // Frames stay >= 0: move forward unless the window starts past frame 0.
          bool back = w.lo[3] > 0.5 / kFps && rng() % 2 == 0;
          map.c[3] = (back ? -1.0 : 1.0) / kFps;
          break;
        }
      }
      auto keys = Selected(*m, w, 0);
      std::vector<Point> moved;
      for (const Key& k : keys) {
        moved.push_back(TransformPoint(m->points.at(k), map));
        m->points.erase(k);
      }
      for (const Point& q : moved) m->points[{q.frame, q.id}] = q;
      Selection sel;
      sel.region = w;
      s.txn.Transform(std::move(sel), map);
      s.what += std::string(" ") + kind + "(" + std::to_string(keys.size()) + ")";
    }
  }
  s.expect_lsn = ++m->lsn;
  return s;
}

// ------------------------------------------------------------------------------------------
// Child side

struct Ack {
  enum Kind : uint32_t { kOpened = 1, kStep = 2, kBulkStart = 3, kBulkDone = 4 };
  uint32_t kind = 0;
  uint32_t step = 0;
  uint64_t lsn = 0;
  // The background work done so far: the kill lands among merges and checkpoints.
  uint32_t merges = 0, checkpoints = 0;
};

void SendAck(int fd, const Ack& a) {
  // 24 bytes < PIPE_BUF: atomic; the parent sees whole acks or none.
  if (::write(fd, &a, sizeof(a)) != static_cast<ssize_t>(sizeof(a))) ::_exit(5);
}

[[noreturn]] void ChildFail(const std::string& msg) {
  std::fprintf(stderr, "crash_test child: %s\n", msg.c_str());
  ::_exit(3);
}

// Runs the workload until killed (or kMaxSteps). Never returns.
[[noreturn]] void RunWorkloadChild(const std::string& dir, const Options& opts, uint64_t seed,
                                   int fd) {
  auto db = Database::Open(dir, opts);
  if (!db.ok()) ChildFail("open: " + db.status().ToString());
  auto ds = (*db)->GetDataset(kDatasetName);
  if (!ds.ok()) ChildFail("dataset: " + ds.status().ToString());
  SendAck(fd, {Ack::kOpened, 0, 0});
  std::mt19937_64 rng(seed);
  Model model;
  for (int i = 0; i < kMaxSteps; ++i) {
    Step s = NextStep(rng, &model);
    Ack a{Ack::kStep, static_cast<uint32_t>(i), 0};
    if (s.kind == Step::kBulk) {
      size_t n = s.bulk.size();
      auto r = (*ds)->BulkLoad(s.frame, std::move(s.bulk));
      if (!r.ok())
        ChildFail("step " + std::to_string(i) + " " + s.what + ": " + r.status().ToString());
      if (*r != n)
        ChildFail("step " + std::to_string(i) + ": bulk load reported " + std::to_string(*r));
      a.lsn = model.lsn;
    } else {
      auto r = (*ds)->Commit(s.txn);
      if (!r.ok())
        ChildFail("step " + std::to_string(i) + " " + s.what + ": " + r.status().ToString());
      if (r->lsn != s.expect_lsn) {
        ChildFail("step " + std::to_string(i) + ": lsn " + std::to_string(r->lsn) + ", expected " +
                  std::to_string(s.expect_lsn));
      }
      if (r->assigned_ids != s.expect_ids) {
        ChildFail("step " + std::to_string(i) + ": assigned ids differ from 1, 2, 3, ...");
      }
      a.lsn = r->lsn;
    }
    if (i % 9 == 8) {
      // Into the cold tier, so that kills also land in compactions (and in the thaws that the
      // next writes to those frames cause).
      auto c = (*ds)->Compact(0, UINT32_MAX);
      if (!c.ok()) ChildFail("step " + std::to_string(i) + " compact: " + c.status().ToString());
    }
    const DatasetStats st = (*ds)->Stats();
    a.merges = static_cast<uint32_t>(st.merges);
    a.checkpoints = static_cast<uint32_t>(st.checkpoints);
    SendAck(fd, a);
  }
  ::_exit(0);  // no destructors: as abrupt as a kill, minus the timing
}

// Opens the dataset (running recovery) and exits without closing it.
[[noreturn]] void RunRecoveryChild(const std::string& dir, const Options& opts, int fd) {
  auto db = Database::Open(dir, opts);
  if (!db.ok()) ChildFail("open: " + db.status().ToString());
  SendAck(fd, {Ack::kOpened, 0, 0});
  auto ds = (*db)->GetDataset(kDatasetName);
  if (!ds.ok()) ChildFail("recovery: " + ds.status().ToString());
  ::_exit(0);
}

struct ChildResult {
  std::vector<Ack> acks;
  bool killed = false;  // died of our SIGKILL (else: exited by itself)
  int exit_code = 0;
  double ran_ms = 0;  // from the Opened ack to the kill
};

// Forks `body(write_fd)`; after its Opened ack waits `delay_us` and SIGKILLs it.
template <typename Body>
ChildResult ForkAndKill(Body body, int64_t delay_us) {
  ChildResult res;
  int fds[2];
  if (::pipe(fds) != 0) {
    ADD_FAILURE() << "pipe: " << std::strerror(errno);
    return res;
  }
  (void)::fcntl(fds[1], F_SETPIPE_SZ, 1 << 20);  // room for every ack without blocking
  std::fflush(stdout);
  std::fflush(stderr);
  pid_t pid = ::fork();
  if (pid < 0) {
    ADD_FAILURE() << "fork: " << std::strerror(errno);
    return res;
  }
  if (pid == 0) {
    ::close(fds[0]);
    body(fds[1]);
    ::_exit(9);  // not reached: every body exits
  }
  ::close(fds[1]);
  auto read_ack = [&](Ack* a) {
    size_t got = 0;
    auto* p = reinterpret_cast<char*>(a);
    while (got < sizeof(Ack)) {
      ssize_t r = ::read(fds[0], p + got, sizeof(Ack) - got);
      if (r < 0 && errno == EINTR) continue;
      if (r <= 0) return false;
      got += static_cast<size_t>(r);
    }
    return true;
  };
  Ack first;
  bool opened = read_ack(&first);
  auto t0 = std::chrono::steady_clock::now();
  if (opened) {
    res.acks.push_back(first);
    if (delay_us > 0) ::usleep(static_cast<useconds_t>(delay_us));
  }
  ::kill(pid, SIGKILL);
  res.ran_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  res.killed = WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL;
  res.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  Ack a;
  while (read_ack(&a)) res.acks.push_back(a);
  ::close(fds[0]);
  return res;
}

void CreateEmptyDataset(const std::string& dir, const Options& opts) {
  auto db = Database::Open(dir, opts);
  ASSERT_TRUE(db.ok()) << db.status().ToString();
  DatasetInfo info;
  info.name = kDatasetName;
  info.fps = kFps;
  auto ds = (*db)->CreateDataset(info);
  ASSERT_TRUE(ds.ok()) << ds.status().ToString();
}

std::vector<std::string> ListNames(const std::string& dir) {
  std::vector<std::string> out;
  std::error_code ec;
  for (const auto& e : std::filesystem::directory_iterator(dir, ec)) {
    out.push_back(e.path().filename().string());
  }
  std::sort(out.begin(), out.end());
  return out;
}

// Full and windowed queries agree with `want`; Info and Check agree too.
void ExpectMatches(Dataset& ds, const PointMap& want, uint64_t want_lsn, uint64_t seed,
                   const std::string& when) {
  SCOPED_TRACE(when);
  PointMap got;
  std::vector<Point> dups;
  Status st = Collect(ds, Everything(), {}, &got, &dups);
  ASSERT_TRUE(st.ok()) << st.ToString();
  EXPECT_TRUE(dups.empty()) << dups.size() << " points returned twice, e.g. " << Describe(dups[0]);
  EXPECT_EQ(Diff(got, want), "");
  DatasetInfo info = ds.Info();
  EXPECT_EQ(info.last_lsn, want_lsn);
  EXPECT_EQ(info.point_count, want.size());
  // Windowed and label-filtered queries against brute force over the model.
  std::mt19937_64 rng(seed ^ 0x5eedull);
  for (int q = 0; q < 6; ++q) {
    Window w = RandomWindow(rng, kFrameSpan + 1);
    QueryOptions qo;
    qo.label_mask = q % 2 == 0 ? 0u : (1u << (rng() % 5));
    qo.batch_points = 1 + rng() % 500;
    PointMap sub, expect;
    std::vector<Point> sub_dups;
    st = Collect(ds, w, qo, &sub, &sub_dups);
    ASSERT_TRUE(st.ok()) << st.ToString();
    EXPECT_TRUE(sub_dups.empty());
    for (const auto& [k, p] : want) {
      if (qo.label_mask != 0 && (p.label & qo.label_mask) == 0) continue;
      if (InWindow(w, p)) expect.emplace(k, p);
    }
    EXPECT_EQ(Diff(sub, expect), "") << "window query " << q;
  }
  auto problems = ds.Check();
  EXPECT_TRUE(problems.empty()) << problems.size()
                                << " problems, first: " << (problems.empty() ? "" : problems[0]);
}

int g_background_kills = 0;  // seeds killed after the merger had started working

// One seed: run, kill, recover, verify, write more, reopen twice.
void CrashOnce(uint64_t seed) {
  SCOPED_TRACE("seed " + std::to_string(seed));
  TempDir tmp;
  const std::string dir = tmp.path() + "/db";
  const bool sync = seed % 2 == 0;
  const bool small_log = seed % 3 == 0;
  const Options opts = CrashOptions(sync, small_log);
  CreateEmptyDataset(dir, opts);
  if (::testing::Test::HasFatalFailure()) return;

  std::mt19937_64 timing(seed * 7919 + 17);
  const int64_t delay_us = static_cast<int64_t>(timing() % 1'200'000);
  ChildResult child = ForkAndKill([&](int fd) { RunWorkloadChild(dir, opts, seed, fd); }, delay_us);
  ASSERT_FALSE(child.acks.empty())
      << "the child never opened the database (exit code " << child.exit_code << ")";
  ASSERT_TRUE(child.killed || child.exit_code == 0)
      << "the child failed by itself with exit code " << child.exit_code << " (see stderr)";
  const size_t k = child.acks.size() - 1;  // acknowledged operations

  // Replay: the model after k and after k + 1 operations; acks must match the replay.
  std::mt19937_64 rng(seed);
  Model model;
  for (size_t i = 0; i < k; ++i) {
    Step s = NextStep(rng, &model);
    const Ack& a = child.acks[i + 1];
    ASSERT_EQ(a.kind, Ack::kStep);
    ASSERT_EQ(a.step, i);
    ASSERT_EQ(a.lsn, model.lsn) << "step " << i << ": " << s.what;
  }
  Model after_k = model;
  std::string next_what = "(none: the workload finished)";
  if (k < static_cast<size_t>(kMaxSteps)) next_what = NextStep(rng, &model).what;
  const Model& after_k1 = model;

  // Odd seeds: crash again, this time during recovery.
  std::string recovery_kill = "";
  if (seed % 2 == 1) {
    const int64_t rdelay = static_cast<int64_t>(timing() % 40'000);
    ChildResult rec = ForkAndKill([&](int fd) { RunRecoveryChild(dir, opts, fd); }, rdelay);
    ASSERT_TRUE(rec.killed || rec.exit_code == 0)
        << "recovery failed in the child, exit code " << rec.exit_code;
    recovery_kill = rec.killed ? "; recovery killed after " + std::to_string(rdelay / 1000) + " ms"
                               : "; recovery finished before the kill";
  }

  auto db = Database::Open(dir, opts);
  ASSERT_TRUE(db.ok()) << db.status().ToString();
  auto ds = (*db)->GetDataset(kDatasetName);
  ASSERT_TRUE(ds.ok()) << "recovery failed: " << ds.status().ToString();

  PointMap got;
  std::vector<Point> dups;
  Status st = Collect(**ds, Everything(), {}, &got, &dups);
  ASSERT_TRUE(st.ok()) << st.ToString();
  const uint64_t lsn = (*ds)->Info().last_lsn;
  const bool is_k = got == after_k.points && lsn == after_k.lsn;
  const bool is_k1 = got == after_k1.points && lsn == after_k1.lsn;
  ASSERT_TRUE(is_k || is_k1) << "recovered state (last_lsn " << lsn
                             << ") is neither the model after " << k
                             << " acknowledged operations (lsn " << after_k.lsn
                             << ") nor after one more (lsn " << after_k1.lsn << ": " << next_what
                             << ")\n vs k:   " << Diff(got, after_k.points)
                             << "\n vs k+1: " << Diff(got, after_k1.points);
  std::printf(
      "[ seed %3llu ] sync=%d small_log=%d killed after %4.0f ms (%u merges, %u checkpoints "
      "done): %3zu ops acked, recovered %s, %zu points%s; next op:%s\n",
      static_cast<unsigned long long>(seed), sync, small_log, child.ran_ms,
      child.acks.back().merges, child.acks.back().checkpoints, k, is_k ? "k  " : "k+1",
      after_k.points.size(), recovery_kill.c_str(), next_what.c_str());
  g_background_kills += child.acks.back().merges > 0 ? 1 : 0;
  Model expect = is_k ? after_k : after_k1;
  ExpectMatches(**ds, expect.points, expect.lsn, seed, "after recovery");
  if (::testing::Test::HasFailure()) return;

  // The recovered dataset takes new commits, with ids that collide with no live point.
  Transaction txn;
  std::mt19937_64 more(seed + 1000);
  std::vector<Point> pts;
  for (int i = 0; i < 5; ++i) pts.push_back(RandomPoint(more, 3));
  txn.Insert(pts);
  auto c = (*ds)->Commit(txn);
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  EXPECT_EQ(c->lsn, expect.lsn + 1);
  ASSERT_EQ(c->assigned_ids.size(), pts.size());
  for (size_t i = 0; i < pts.size(); ++i) {
    pts[i].id = c->assigned_ids[i];
    EXPECT_TRUE(expect.points.emplace(Key{3, pts[i].id}, pts[i]).second)
        << "assigned id " << pts[i].id << " is already live in frame 3";
  }
  expect.lsn = c->lsn;
  ds->reset();
  db->reset();

  // Reopening twice gives the same dataset each time.
  for (int round = 0; round < 2; ++round) {
    auto db2 = Database::Open(dir, opts);
    ASSERT_TRUE(db2.ok()) << db2.status().ToString();
    auto ds2 = (*db2)->GetDataset(kDatasetName);
    ASSERT_TRUE(ds2.ok()) << ds2.status().ToString();
    ExpectMatches(**ds2, expect.points, expect.lsn, seed + 1 + static_cast<uint64_t>(round),
                  "reopen " + std::to_string(round + 1));
    if (::testing::Test::HasFailure()) return;
  }
  // Nothing left over from the crash: no temporary files.
  for (const char* sub : {"", "/frames", "/trees"}) {
    for (const std::string& n : ListNames(dir + "/" + kDatasetName + sub)) {
      EXPECT_FALSE(n.ends_with(".tmp")) << "leftover " << sub << "/" << n;
    }
  }
}

// Seeds 1..20 by default (~20 s); HVDB_CRASH_SEEDS=first:count runs others, for soak runs.
TEST(CrashTest, KillDuringWorkloadRecoversExactlyTheAcknowledgedCommits) {
  const auto start = std::chrono::steady_clock::now();
  uint64_t first = 1, count = 20;
  if (const char* env = std::getenv("HVDB_CRASH_SEEDS")) {
    unsigned long long a = 0, b = 0;
    if (std::sscanf(env, "%llu:%llu", &a, &b) == 2) {
      first = a;
      count = b;
    }
  }
  g_background_kills = 0;
  for (uint64_t seed = first; seed < first + count; ++seed) {
    CrashOnce(seed);
    if (HasFailure()) break;  // one seed's diagnostics are enough
  }
  // With a 64-point T0 the merger is busy all along: most kills land while it works.
  if (!HasFailure()) {
    EXPECT_GE(g_background_kills, static_cast<int>(count) / 2);
  }
  double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  RecordProperty("seconds", std::to_string(s));
}

// ------------------------------------------------------------------------------------------
// Killed during one large bulk load: afterwards the frame is either complete or absent.

constexpr uint32_t kBigFrame = 1;
constexpr size_t kBigPoints = 200'000;

std::vector<Point> BigFrame() {
  std::mt19937_64 rng(4242);
  std::vector<Point> pts;
  pts.reserve(kBigPoints);
  for (size_t i = 0; i < kBigPoints; ++i) pts.push_back(RandomPoint(rng, kBigFrame));
  return pts;
}

[[noreturn]] void RunBulkChild(const std::string& dir, const Options& opts, int fd) {
  std::vector<Point> pts = BigFrame();
  auto db = Database::Open(dir, opts);
  if (!db.ok()) ChildFail("open: " + db.status().ToString());
  auto ds = (*db)->GetDataset(kDatasetName);
  if (!ds.ok()) ChildFail("dataset: " + ds.status().ToString());
  SendAck(fd, {Ack::kOpened, 0, 0});
  auto r = (*ds)->BulkLoad(kBigFrame, std::move(pts));
  if (!r.ok()) ChildFail("bulk load: " + r.status().ToString());
  SendAck(fd, {Ack::kBulkDone, 0, 0});
  ::_exit(0);
}

TEST(CrashTest, KillDuringLargeBulkLoadLeavesFrameWholeOrAbsent) {
  const Options opts = CrashOptions(/*sync=*/true, /*small_log=*/false);
  // The base state: frame 0 with 1000 points (ids 1..1000), and one transaction.
  PointMap base;
  std::mt19937_64 rng(99);
  std::vector<Point> frame0;
  for (int i = 0; i < 1000; ++i) frame0.push_back(RandomPoint(rng, 0));
  for (size_t i = 0; i < frame0.size(); ++i) {
    Point p = frame0[i];
    p.id = i + 1;
    base[{0, p.id}] = p;
  }
  PointMap full = base;
  {
    std::vector<Point> big = BigFrame();
    for (size_t i = 0; i < big.size(); ++i) {
      Point p = big[i];
      p.id = frame0.size() + 1 + i;  // bulk-load ids continue after frame 0's
      full[{kBigFrame, p.id}] = p;
    }
  }
  // Kill points as fractions of an undisturbed load's duration (measured by run 0, which is
  // not killed; 2.0 = let it finish).
  const double fractions[] = {2.0, 0.05, 0.25, 0.5, 0.75, 0.95};
  double load_ms = 0;
  int complete = 0, absent = 0;
  size_t orphans = 0;
  for (double fraction : fractions) {
    SCOPED_TRACE("kill at " + std::to_string(fraction) + " of the load");
    TempDir tmp;
    const std::string dir = tmp.path() + "/db";
    {
      CreateEmptyDataset(dir, opts);
      if (HasFatalFailure()) return;
      auto db = Database::Open(dir, opts);
      ASSERT_TRUE(db.ok());
      auto ds = (*db)->GetDataset(kDatasetName);
      ASSERT_TRUE(ds.ok());
      auto r = (*ds)->BulkLoad(0, frame0);
      ASSERT_TRUE(r.ok()) << r.status().ToString();
    }
    int64_t delay = fraction >= 1.5 ? 30'000'000 : static_cast<int64_t>(fraction * load_ms * 1000);
    if (fraction >= 1.5) {
      // Run 0: wait for completion (the long delay is cut short by reading the done ack).
      int fds[2];
      ASSERT_EQ(::pipe(fds), 0);
      std::fflush(stdout);
      pid_t pid = ::fork();
      ASSERT_GE(pid, 0);
      if (pid == 0) {
        ::close(fds[0]);
        RunBulkChild(dir, opts, fds[1]);
      }
      ::close(fds[1]);
      Ack a;
      ASSERT_EQ(::read(fds[0], &a, sizeof(a)), static_cast<ssize_t>(sizeof(a)));
      auto t0 = std::chrono::steady_clock::now();
      ASSERT_EQ(::read(fds[0], &a, sizeof(a)), static_cast<ssize_t>(sizeof(a)));
      EXPECT_EQ(a.kind, Ack::kBulkDone);
      load_ms =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      int status = 0;
      ::waitpid(pid, &status, 0);
      ::close(fds[0]);
      ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0);
    } else {
      ChildResult child = ForkAndKill([&](int fd) { RunBulkChild(dir, opts, fd); }, delay);
      ASSERT_FALSE(child.acks.empty());
      ASSERT_TRUE(child.killed || child.exit_code == 0) << "exit code " << child.exit_code;
    }

    auto db = Database::Open(dir, opts);
    ASSERT_TRUE(db.ok()) << db.status().ToString();
    auto ds = (*db)->GetDataset(kDatasetName);
    ASSERT_TRUE(ds.ok()) << "recovery failed: " << ds.status().ToString();
    PointMap got;
    std::vector<Point> dups;
    Status st = Collect(**ds, Everything(), {}, &got, &dups);
    ASSERT_TRUE(st.ok()) << st.ToString();
    EXPECT_TRUE(dups.empty());
    const bool is_full = got == full, is_base = got == base;
    EXPECT_TRUE(is_full || is_base)
        << "frame 1 is neither complete nor absent:\n vs absent: " << Diff(got, base)
        << "\n vs complete: " << Diff(got, full);
    if (fraction >= 1.5) {
      EXPECT_TRUE(is_full);
    }
    complete += is_full;
    absent += is_base;
    auto problems = (*ds)->Check();
    EXPECT_TRUE(problems.empty()) << problems[0];
    // No temporary files remain. Tree files no frame lists (the interrupted load's output)
    // should be gone too; RecoveryRemovesOrphanTreeFiles checks that, here they are counted.
    size_t kdt = 0;
    for (const std::string& n : ListNames(dir + "/" + kDatasetName + "/trees")) {
      EXPECT_FALSE(n.ends_with(".tmp")) << "leftover trees/" << n;
      kdt += n.ends_with(".kdt");
    }
    orphans += kdt - (*ds)->Stats().trees;
    for (const std::string& n : ListNames(dir + "/" + kDatasetName + "/frames")) {
      EXPECT_FALSE(n.ends_with(".tmp")) << "leftover frames/" << n;
    }
    ds->reset();
    db->reset();
    // Stable on a second open.
    auto db2 = Database::Open(dir, opts);
    ASSERT_TRUE(db2.ok());
    auto ds2 = (*db2)->GetDataset(kDatasetName);
    ASSERT_TRUE(ds2.ok()) << ds2.status().ToString();
    PointMap again;
    st = Collect(**ds2, Everything(), {}, &again, &dups);
    ASSERT_TRUE(st.ok()) << st.ToString();
    EXPECT_EQ(Diff(again, got), "");
  }
  std::printf(
      "[ bulk ] undisturbed 200k-point load: %.0f ms; after the kills: %d complete, %d "
      "absent; %zu orphan tree files left behind\n",
      load_ms, complete, absent, orphans);
  RecordProperty("bulk_load_ms", std::to_string(load_ms));
}

// ------------------------------------------------------------------------------------------
// Recovery housekeeping, deterministically (no kill needed to set the state up).

// Recover() deletes tree files that no frame state lists ("outputs of rebuilds cut short, or
// inputs of finished ones"): here such a file is planted by hand, as a crash between writing a
// tree and persisting its frame state leaves one.
TEST(CrashTest, RecoveryRemovesOrphanTreeFiles) {
  TempDir tmp;
  const std::string dir = tmp.path() + "/db";
  const Options opts = CrashOptions(true, false);
  CreateEmptyDataset(dir, opts);
  ASSERT_FALSE(HasFatalFailure());
  const std::string trees = dir + "/" + kDatasetName + "/trees";
  {
    auto db = Database::Open(dir, opts);
    ASSERT_TRUE(db.ok());
    auto ds = (*db)->GetDataset(kDatasetName);
    ASSERT_TRUE(ds.ok());
    std::mt19937_64 rng(3);
    std::vector<Point> pts;
    for (int i = 0; i < 500; ++i) pts.push_back(RandomPoint(rng, 2));
    ASSERT_TRUE((*ds)->BulkLoad(2, pts).ok());
  }
  auto names = ListNames(trees);
  ASSERT_EQ(names.size(), 1u);
  ASSERT_EQ(names[0], "00000002-0000000000000001.kdt");
  // A complete, valid tree file of frame 2 with sequence number 7, listed by no frame.
  const std::string orphan = trees + "/00000002-0000000000000007.kdt";
  std::filesystem::copy_file(trees + "/" + names[0], orphan);
  auto db = Database::Open(dir, opts);
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset(kDatasetName);
  ASSERT_TRUE(ds.ok()) << ds.status().ToString();
  EXPECT_EQ((*ds)->Info().point_count, 500u);
  EXPECT_FALSE(std::filesystem::exists(orphan))
      << "recovery left the unreferenced tree file behind (ParseTreeFileName rejects the "
         "29-character names TreeFileName makes, so Recover never recognises a tree file)";
  EXPECT_EQ(ListNames(trees).size(), (*ds)->Stats().trees);
}

// Ids are "unique within a dataset". After a reopen the engine must not hand out again the id
// of a point that was deleted: Revert of that delete would then bring back a second point
// with the same id (and clients holding the old id would address the new point).
TEST(CrashTest, IdsOfDeletedPointsAreNotReissuedAfterReopen) {
  TempDir tmp;
  const std::string dir = tmp.path() + "/db";
  const Options opts = CrashOptions(true, false);
  CreateEmptyDataset(dir, opts);
  ASSERT_FALSE(HasFatalFailure());
  uint64_t max_id = 0, delete_lsn = 0;
  {
    auto db = Database::Open(dir, opts);
    ASSERT_TRUE(db.ok());
    auto ds = (*db)->GetDataset(kDatasetName);
    ASSERT_TRUE(ds.ok());
    std::mt19937_64 rng(4);
    std::vector<Point> pts;
    for (int i = 0; i < 3; ++i) pts.push_back(RandomPoint(rng, 0));
    Transaction ins;
    ins.Insert(pts);
    auto c = (*ds)->Commit(ins);
    ASSERT_TRUE(c.ok());
    max_id = c->assigned_ids.back();
    const Point& last = pts.back();
    Transaction del;
    del.Delete(max_id, 0, {last.x, last.y, last.z});
    auto d = (*ds)->Commit(del);
    ASSERT_TRUE(d.ok()) << d.status().ToString();
    delete_lsn = d->lsn;
  }
  auto db = Database::Open(dir, opts);
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset(kDatasetName);
  ASSERT_TRUE(ds.ok());
  std::mt19937_64 rng(5);
  Transaction ins;
  ins.Insert({RandomPoint(rng, 0)});
  auto c = (*ds)->Commit(ins);
  ASSERT_TRUE(c.ok());
  EXPECT_GT(c->assigned_ids[0], max_id) << "id " << max_id << " of a deleted point was reissued";
  auto r = (*ds)->Revert(delete_lsn);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  PointMap got;
  std::vector<Point> dups;
  ASSERT_TRUE(Collect(**ds, Everything(), {}, &got, &dups).ok());
  EXPECT_TRUE(dups.empty()) << "two live points share id " << (dups.empty() ? 0 : dups[0].id)
                            << " in frame 0";
}

}  // namespace
}  // namespace hvdb
