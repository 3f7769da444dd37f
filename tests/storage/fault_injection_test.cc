// Faults injected through the I/O seam (storage/env.h, tests/storage/fault_env.h): a crash
// between any two mutating system calls followed by a power loss, failed writes (ENOSPC) and
// syncs (EIO), failed and short reads. After each, the database reopens consistent with a
// brute-force model and nothing acknowledged is lost.
//
// The workload (seeded) commits inserts with explicit ids, deletes, label edits and bulk loads,
// with a 64-point T0 and a 16 KiB log so that the merger and checkpoints run throughout. The
// model after a failed operation is computable either way (applied or not): an operation that
// fails after its point of no return (e.g. a directory sync after the rename that made a bulk
// load visible) may have taken effect, as docs/ARCHITECTURE.md says.
#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <map>
#include <thread>
#include <random>
#include <set>

#include "storage/database.h"
#include "tests/storage/fault_env.h"
#include "tests/storage/test_util.h"

namespace hvdb::testing {
namespace {

constexpr const char* kName = "video";
constexpr int kSteps = 36;

using Key = std::pair<uint32_t, uint64_t>;
using Model = std::map<Key, Point>;

struct Op {
  enum Kind { kInsert, kDelete, kLabel, kBulk, kCheckpoint, kCompact } kind = kInsert;
  uint32_t frame = 0;
  std::vector<Point> points;  // insert / bulk: with ids; delete: the points to delete
  std::vector<uint64_t> ids;  // label
  uint32_t bits = 0;
};

// Step `i` of workload `seed` against the model as it is (deterministic in both).
Op MakeOp(uint64_t seed, int i, const Model& m, uint64_t* next_id) {
  std::mt19937_64 rng(seed * 1000003 + static_cast<uint64_t>(i));
  Op op;
  const int r = static_cast<int>(rng() % 100);
  auto live_in = [&](uint32_t f) {
    std::vector<Point> out;
    for (auto it = m.lower_bound({f, 0}); it != m.end() && it->first.first == f; ++it) {
      out.push_back(it->second);
    }
    return out;
  };
  op.frame = static_cast<uint32_t>(rng() % 4);
  if (i % 12 == 11) {
    op.kind = Op::kCheckpoint;
  } else if (i % 12 == 5) {
    op.kind = Op::kCompact;  // into the cold tier (later writes to the frame thaw it)
  } else if (r < 55) {
    op.kind = Op::kInsert;
    const int n = 1 + static_cast<int>(rng() % 150);
    for (int k = 0; k < n; ++k) {
      Point p = RandomPoint(rng, op.frame);
      p.id = (*next_id)++;
      op.points.push_back(p);
    }
  } else if (r < 70) {
    op.kind = Op::kDelete;
    auto live = live_in(op.frame);
    for (int k = 0; k < 6 && !live.empty(); ++k) {
      size_t j = rng() % live.size();
      op.points.push_back(live[j]);
      live.erase(live.begin() + static_cast<std::ptrdiff_t>(j));
    }
  } else if (r < 85) {
    op.kind = Op::kLabel;
    op.bits = 1u << (rng() % 4);
    auto live = live_in(op.frame);
    for (int k = 0; k < 20 && !live.empty(); ++k) op.ids.push_back(live[rng() % live.size()].id);
    std::sort(op.ids.begin(), op.ids.end());
    op.ids.erase(std::unique(op.ids.begin(), op.ids.end()), op.ids.end());
  } else {
    op.kind = Op::kBulk;
    op.frame = 4 + static_cast<uint32_t>(rng() % 2);
    for (int k = 0; k < 700; ++k) {
      Point p = RandomPoint(rng, op.frame);
      p.id = (*next_id)++;
      op.points.push_back(p);
    }
  }
  return op;
}

void ApplyToModel(const Op& op, Model* m) {
  switch (op.kind) {
    case Op::kInsert:
    case Op::kBulk:
      for (const Point& p : op.points) (*m)[{p.frame, p.id}] = p;
      break;
    case Op::kDelete:
      for (const Point& p : op.points) m->erase({p.frame, p.id});
      break;
    case Op::kLabel:
      for (uint64_t id : op.ids) (*m)[{op.frame, id}].label |= op.bits;
      break;
    case Op::kCheckpoint:
    case Op::kCompact: break;
  }
}

Status RunOp(Dataset& ds, const Op& op) {
  Transaction txn;
  switch (op.kind) {
    case Op::kInsert: txn.Insert(op.points); break;
    case Op::kDelete:
      if (op.points.empty()) return Status::OK();
      for (const Point& p : op.points) txn.Delete(p.id, p.frame, {p.x, p.y, p.z});
      break;
    case Op::kLabel: {
      if (op.ids.empty()) return Status::OK();
      Selection sel;
      for (uint64_t id : op.ids) sel.ids.push_back({op.frame, id});
      txn.SetLabel(sel, op.bits, true);
      break;
    }
    case Op::kBulk: return ds.BulkLoad(op.frame, op.points).status();
    case Op::kCheckpoint: return ds.Checkpoint();
    case Op::kCompact: return ds.Compact(op.frame, op.frame).status();
  }
  return ds.Commit(txn).status();
}

Options FaultOptions(Env* env, bool sync) {
  Options o;
  o.cache_bytes = 8u << 20;
  o.block_size = 4096;
  o.t0_points = 64;
  o.wal_checkpoint_bytes = 16u << 10;
  o.sync = sync;
  o.env = env;
  return o;
}

Model Read(Dataset& ds) {
  Model out;
  const double inf = std::numeric_limits<double>::infinity();
  Window w;
  w.lo = {-inf, -inf, -inf, -inf};
  w.hi = {inf, inf, inf, inf};
  auto cur = ds.Query(w);
  EXPECT_TRUE(cur.ok()) << cur.status().ToString();
  if (!cur.ok()) return out;
  Batch b;
  for (;;) {
    auto more = (*cur)->Next(&b);
    EXPECT_TRUE(more.ok()) << more.status().ToString();
    if (!more.ok()) break;
    for (const Point& p : b.points) {
      EXPECT_TRUE(out.emplace(Key{p.frame, p.id}, p).second) << "duplicate " << p.id;
    }
    if (!*more) break;
  }
  return out;
}

std::string Diff(const Model& got, const Model& want) {
  if (got == want) return "";
  size_t missing = 0, extra = 0, changed = 0;
  for (const auto& [k, p] : want) {
    auto it = got.find(k);
    if (it == got.end()) {
      ++missing;
    } else if (!(it->second == p)) {
      ++changed;
    }
  }
  for (const auto& [k, p] : got) extra += want.count(k) ? 0 : 1;
  return std::to_string(missing) + " missing, " + std::to_string(extra) + " extra, " +
         std::to_string(changed) + " changed";
}

struct RunResult {
  Model acked;         // the model after every acknowledged operation
  Model with_failed;   // ... plus the effect of the first failed one
  int failed = -1;     // step of the first failed operation
  int steps_run = 0;
};

// Runs the workload; stops at the first failure when `stop_on_error`.
RunResult RunWorkload(Database& db, uint64_t seed, bool stop_on_error) {
  RunResult r;
  auto ds = db.GetDataset(kName);
  if (!ds.ok()) {
    ADD_FAILURE() << ds.status().ToString();
    return r;
  }
  uint64_t next_id = 1;
  for (int i = 0; i < kSteps; ++i) {
    Op op = MakeOp(seed, i, r.acked, &next_id);
    Status s = RunOp(**ds, op);
    r.steps_run = i + 1;
    if (s.ok()) {
      ApplyToModel(op, &r.acked);
      if (r.failed < 0) r.with_failed = r.acked;
      else ApplyToModel(op, &r.with_failed);
      continue;
    }
    EXPECT_FALSE(s.message().empty());
    if (r.failed < 0) {
      r.failed = i;
      r.with_failed = r.acked;
      ApplyToModel(op, &r.with_failed);
    }
    if (stop_on_error) break;
  }
  if (r.failed < 0) r.with_failed = r.acked;
  return r;
}

class FaultInjectionTest : public ::testing::Test {
 protected:
  void SetUp() override { env_ = std::make_unique<FaultEnv>(tmp_.path() + "/aside"); }
  std::string Dir() const { return tmp_.path() + "/db"; }
  void Create(bool sync) {
    auto db = Database::Open(Dir(), FaultOptions(env_.get(), sync));
    ASSERT_TRUE(db.ok()) << db.status().ToString();
    DatasetInfo info;
    info.name = kName;
    ASSERT_TRUE((*db)->CreateDataset(info).ok());
  }
  // Reopens with no faults; the state must be `a` or `b`, and the dataset must check clean.
  void ExpectRecovered(const Model& a, const Model& b, const std::string& what) {
    auto db = Database::Open(Dir(), FaultOptions(env_.get(), true));
    ASSERT_TRUE(db.ok()) << what << ": " << db.status().ToString();
    auto ds = (*db)->GetDataset(kName);
    ASSERT_TRUE(ds.ok()) << what << ": recovery failed: " << ds.status().ToString();
    Model got = Read(**ds);
    EXPECT_TRUE(got == a || got == b) << what << ": vs acknowledged: " << Diff(got, a)
                                      << "; vs with the failed op: " << Diff(got, b);
    auto problems = (*ds)->Check();
    EXPECT_TRUE(problems.empty()) << what << ": " << problems.front();
  }
  TempDir tmp_;
  std::unique_ptr<FaultEnv> env_;
};

// Crash points: every mutating call of the workload by default up to a bound, all of them with
// HVDB_FAULT_ALL=1 (soak).
TEST_F(FaultInjectionTest, CrashBetweenAnyTwoSyscallsThenPowerLossLosesNothingAcknowledged) {
  uint64_t total = 0;
  {
    TempDir probe;
    FaultEnv env(probe.path() + "/aside");
    auto db = Database::Open(probe.path() + "/db", FaultOptions(&env, true));
    ASSERT_TRUE(db.ok());
    DatasetInfo info;
    info.name = kName;
    ASSERT_TRUE((*db)->CreateDataset(info).ok());
    uint64_t before = env.mutating_calls();
    RunResult r = RunWorkload(**db, 1, true);
    ASSERT_EQ(r.failed, -1);
    total = env.mutating_calls() - before;
  }
  const bool all = std::getenv("HVDB_FAULT_ALL") != nullptr;
  const uint64_t stride = all ? 1 : std::max<uint64_t>(1, total / 60);
  int crashes = 0;
  for (uint64_t k = 1; k <= total + 5; k += stride) {
    SCOPED_TRACE("crash after " + std::to_string(k) + " of ~" + std::to_string(total) + " calls");
    std::filesystem::remove_all(Dir());
    env_->Reset();
    Create(true);
    if (HasFatalFailure()) return;
    RunResult r;
    {
      auto db = Database::Open(Dir(), FaultOptions(env_.get(), true));
      ASSERT_TRUE(db.ok());
      env_->CrashAfter(k);
      r = RunWorkload(**db, 1, true);
    }  // the "dead process" is torn down: none of its writes get through any more
    crashes += env_->crashed() ? 1 : 0;
    env_->PowerLoss();
    // A crashed operation never reached its point of no return here: exactly the acked state.
    ExpectRecovered(r.acked, r.acked, "crash after call " + std::to_string(k));
    if (HasFailure()) return;
  }
  std::printf("[ fault ] %llu mutating calls in the workload; %d crash points, all recovered\n",
              static_cast<unsigned long long>(total), crashes);
  EXPECT_GT(crashes, 10);
}

TEST_F(FaultInjectionTest, FailedWritesAndSyncsLoseNothingAcknowledged) {
  int fired = 0;
  for (int nth = 1; nth <= 40; nth += 3) {
    for (bool on_sync : {false, true}) {
      const std::string what = (on_sync ? "sync " : "write ") + std::to_string(nth);
      SCOPED_TRACE(what);
      std::filesystem::remove_all(Dir());
      env_->Reset();
      Create(true);
      RunResult r;
      {
        auto db = Database::Open(Dir(), FaultOptions(env_.get(), true));
        ASSERT_TRUE(db.ok());
        if (on_sync) {
          env_->FailSync(static_cast<uint64_t>(nth), Status::IOError("fsync: Input/output error"));
        } else {
          env_->FailWrite(static_cast<uint64_t>(nth),
                          Status::IOError("write: No space left on device"));
        }
        uint64_t before = env_->faults_fired();
        r = RunWorkload(**db, 2, false);  // keeps going after the failure
        fired += static_cast<int>(env_->faults_fired() - before);
        // The open dataset serves on, with exactly what it acknowledged (or the failed op).
        auto ds = (*db)->GetDataset(kName);
        ASSERT_TRUE(ds.ok());
        ASSERT_TRUE((*ds)->WaitForMerges().ok());
        Model live = Read(**ds);
        EXPECT_TRUE(live == r.acked || live == r.with_failed) << Diff(live, r.acked);
      }
      ExpectRecovered(r.acked, r.with_failed, what);
      if (HasFailure()) return;
    }
  }
  EXPECT_GT(fired, 20);
}

TEST_F(FaultInjectionTest, ReadErrorsAndShortReadsFailTheQueryNotTheDatabase) {
  Create(true);
  Model model;
  {
    auto db = Database::Open(Dir(), FaultOptions(env_.get(), true));
    ASSERT_TRUE(db.ok());
    model = RunWorkload(**db, 3, true).acked;
  }
  auto db = Database::Open(Dir(), FaultOptions(env_.get(), true));  // a cold cache
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset(kName);
  ASSERT_TRUE(ds.ok());
  ASSERT_TRUE((*ds)->WaitForMerges().ok());  // the merger reads nothing while faults are set
  const double inf = std::numeric_limits<double>::infinity();
  Window w;
  w.lo = {-inf, -inf, -inf, -inf};
  w.hi = {inf, inf, inf, inf};
  auto drain = [&]() -> Status {
    HVDB_ASSIGN_OR_RETURN(auto cur, (*ds)->Query(w));
    Batch b;
    for (;;) {
      HVDB_ASSIGN_OR_RETURN(bool more, cur->Next(&b));
      if (!more) return Status::OK();
    }
  };
  // One failed read (of a batch read ahead, or of a single block): a read that failed is not
  // cached, and the query's own read of the block goes through.
  env_->FailRead(1, Status::IOError("read: Input/output error"));
  EXPECT_TRUE(drain().ok());
  (*ds).reset();  // a cold cache again
  (*db).reset();
  db = Database::Open(Dir(), FaultOptions(env_.get(), true));
  ASSERT_TRUE(db.ok());
  ds = (*db)->GetDataset(kName);
  ASSERT_TRUE(ds.ok());
  ASSERT_TRUE((*ds)->WaitForMerges().ok());
  // A device that keeps failing: the query fails with the error, the database does not.
  env_->FailRead(1, Status::IOError("read: Input/output error"), 1u << 30);
  Status s = drain();
  EXPECT_EQ(s.code(), StatusCode::kIOError) << s.ToString();
  env_->Reset();
  env_->ShortRead(1, 1u << 30);
  s = drain();
  EXPECT_EQ(s.code(), StatusCode::kCorruption) << s.ToString();
  EXPECT_NE(s.message().find("truncated"), std::string::npos) << s.ToString();
  env_->Reset();
  // Nothing bad was cached: the next query reads everything, right.
  EXPECT_EQ(Diff(Read(**ds), model), "");
  EXPECT_GE(env_->faults_fired(), 3u);
}

// Group commit: writers committing at once share log writes and syncs.
TEST_F(FaultInjectionTest, ConcurrentCommitsShareSyncs) {
  Create(true);
  auto db = Database::Open(Dir(), FaultOptions(env_.get(), true));
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset(kName);
  ASSERT_TRUE(ds.ok());
  ASSERT_TRUE((*ds)->WaitForMerges().ok());
  constexpr int kThreads = 8, kEach = 25;
  const uint64_t before = env_->syncs();
  std::vector<std::thread> threads;
  std::atomic<int> failures{0};
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      std::mt19937_64 rng(500 + static_cast<uint64_t>(t));
      for (int i = 0; i < kEach; ++i) {
        Transaction txn;
        txn.Insert({RandomPoint(rng, 9)});  // (checkpoints sync too, and are counted)
        if (!(*ds)->Commit(txn).ok()) ++failures;
      }
    });
  }
  for (auto& th : threads) th.join();
  const uint64_t syncs = env_->syncs() - before;
  EXPECT_EQ(failures.load(), 0);
  EXPECT_EQ((*ds)->Info().last_lsn, uint64_t{kThreads * kEach});
  std::printf("[ fault ] %d concurrent commits, %llu syncs\n", kThreads * kEach,
              static_cast<unsigned long long>(syncs));
  EXPECT_LT(syncs, uint64_t{kThreads * kEach}) << "no two commits shared a sync";
}

// Without sync, commits may be lost to a power loss, but only a suffix of them: the state is
// the model after some prefix of the acknowledged operations.
TEST_F(FaultInjectionTest, PowerLossWithoutSyncKeepsAPrefix) {
  Create(false);
  std::vector<Model> prefixes{Model{}};
  {
    Options o = FaultOptions(env_.get(), false);
    o.wal_checkpoint_bytes = 64u << 20;  // no checkpoint syncs the log behind our back
    auto db = Database::Open(Dir(), o);
    ASSERT_TRUE(db.ok());
    auto ds = (*db)->GetDataset(kName);
    ASSERT_TRUE(ds.ok());
    uint64_t next_id = 1;
    for (int i = 0; i < kSteps - 2; ++i) {  // not ending on a checkpoint
      Op op = MakeOp(4, i, prefixes.back(), &next_id);
      ASSERT_TRUE(RunOp(**ds, op).ok());
      Model m = prefixes.back();
      ApplyToModel(op, &m);
      prefixes.push_back(std::move(m));
    }
    env_->CrashNow();  // the close writes nothing
  }
  env_->PowerLoss();
  auto db = Database::Open(Dir(), FaultOptions(env_.get(), true));
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset(kName);
  ASSERT_TRUE(ds.ok()) << ds.status().ToString();
  Model got = Read(**ds);
  size_t match = prefixes.size();
  for (size_t j = 0; j < prefixes.size(); ++j) {
    if (prefixes[j] == got) match = j;
  }
  ASSERT_LT(match, prefixes.size()) << "the state is no prefix of the workload";
  std::printf("[ fault ] power loss without sync kept %zu of %d operations\n", match, kSteps - 2);
  EXPECT_TRUE((*ds)->Check().empty());
}

}  // namespace
}  // namespace hvdb::testing
