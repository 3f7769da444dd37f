// Damaged files: every checksum the format promises is checked, errors name the file and the
// block or record at fault, and no damaged byte ever reaches a query result.
//
// Each case starts from a pristine copy of one data directory (a dataset with a 50,000-point
// frame in 4 KiB blocks), damages one file while no Database has it open, and reopens.
// Log cases use a child process that commits and then exits without closing, so the records
// are still in wal.log (a clean close checkpoints them away).
#include <fcntl.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "storage/coding.h"
#include "storage/database.h"
#include "storage/kdtree_format.h"
#include "storage/point.h"
#include "storage/status.h"
#include "storage/wal.h"

namespace hvdb {
namespace {

namespace fs = std::filesystem;

constexpr const char* kName = "clip";
constexpr size_t kFramePoints = 50'000;
constexpr size_t kWalHeader = kWalHeaderSize;
constexpr size_t kWalRecordHeader = kWalRecordHeaderSize;

Options TestOptions() {
  Options o;
  o.cache_bytes = 8u << 20;
  o.block_size = 4096;
  o.t0_points = 64;  // a 100-point commit overflows T0
  return o;
}

Window Everything() {
  const double inf = std::numeric_limits<double>::infinity();
  Window w;
  w.lo = {-inf, -inf, -inf, -inf};
  w.hi = {inf, inf, inf, inf};
  return w;
}

using Key = std::pair<uint32_t, uint64_t>;
using PointMap = std::map<Key, Point>;

Point RandomPoint(std::mt19937_64& rng, uint32_t frame) {
  std::uniform_real_distribution<float> pos(-5.f, 5.f);
  Point p;
  p.x = pos(rng);
  p.y = pos(rng);
  p.z = pos(rng);
  p.frame = frame;
  p.cov = {1e-3f, 0, 0, 1e-3f, 0, 1e-3f};
  p.label = static_cast<uint32_t>(rng() % 8);
  p.r = static_cast<uint8_t>(rng());
  return p;
}

// Reads a query to exhaustion into `out`; returns the first error.
Status Collect(Dataset& ds, const Region& region, PointMap* out) {
  auto cur = ds.Query(region);
  if (!cur.ok()) return cur.status();
  Batch batch;
  for (;;) {
    auto more = (*cur)->Next(&batch);
    if (!more.ok()) return more.status();
    for (const Point& p : batch.points) (*out)[{p.frame, p.id}] = p;
    if (!*more) return Status::OK();
  }
}

std::string ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

void WriteFile(const std::string& path, const std::string& data) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(data.data(), static_cast<std::streamsize>(data.size()));
}

void FlipByte(const std::string& path, uint64_t offset) {
  std::string d = ReadFile(path);
  ASSERT_LT(offset, d.size()) << path;
  d[offset] = static_cast<char>(d[offset] ^ 0x5a);
  WriteFile(path, d);
}

void Truncate(const std::string& path, uint64_t size) {
  ASSERT_EQ(::truncate(path.c_str(), static_cast<off_t>(size)), 0) << std::strerror(errno);
}

std::vector<std::string> FilesIn(const std::string& dir, const std::string& suffix) {
  std::vector<std::string> out;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    std::string n = e.path().filename().string();
    if (n.ends_with(suffix)) out.push_back(n);
  }
  std::sort(out.begin(), out.end());
  return out;
}

bool Contains(const std::string& haystack, const std::string& needle) {
  return haystack.find(needle) != std::string::npos;
}

// The pristine directory: built once per test binary, copied for every case.
class CorruptionTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    char tmpl[] = "/tmp/hvdb_corrupt_XXXXXX";
    ASSERT_NE(::mkdtemp(tmpl), nullptr);
    root_ = new std::string(tmpl);
    pristine_ = new PointMap;
    const std::string dir = *root_ + "/pristine";
    auto db = Database::Open(dir, TestOptions());
    ASSERT_TRUE(db.ok()) << db.status().ToString();
    DatasetInfo info;
    info.name = kName;
    auto ds = (*db)->CreateDataset(info);
    ASSERT_TRUE(ds.ok()) << ds.status().ToString();
    std::mt19937_64 rng(2024);
    std::vector<Point> pts;
    for (size_t i = 0; i < kFramePoints; ++i) pts.push_back(RandomPoint(rng, 0));
    for (size_t i = 0; i < pts.size(); ++i) {
      Point p = pts[i];
      p.id = i + 1;
      (*pristine_)[{0, p.id}] = p;
    }
    auto r = (*ds)->BulkLoad(0, std::move(pts));
    ASSERT_TRUE(r.ok()) << r.status().ToString();
  }
  static void TearDownTestSuite() {
    if (root_ != nullptr) {
      std::error_code ec;
      fs::remove_all(*root_, ec);
    }
    delete root_;
    delete pristine_;
    root_ = nullptr;
    pristine_ = nullptr;
  }

  void SetUp() override {
    ASSERT_NE(root_, nullptr);
    dir_ = *root_ + "/case_" + ::testing::UnitTest::GetInstance()->current_test_info()->name();
    std::error_code ec;
    fs::remove_all(dir_, ec);
    fs::copy(*root_ + "/pristine", dir_, fs::copy_options::recursive, ec);
    ASSERT_FALSE(ec) << ec.message();
    auto trees = FilesIn(ds_dir() + "/trees", ".kdt");
    ASSERT_EQ(trees.size(), 1u);
    tree_name_ = trees[0];
  }
  void TearDown() override {
    ::chmod((ds_dir() + "/trees").c_str(), 0755);  // in case a permission case stopped early
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }

  std::string ds_dir() const { return dir_ + "/" + kName; }
  std::string tree_path() const { return ds_dir() + "/trees/" + tree_name_; }
  std::string fst_path() const { return ds_dir() + "/frames/00000000.fst"; }
  std::string wal_path() const { return ds_dir() + "/wal.log"; }

  TreeHeader Header() {
    std::string d = ReadFile(tree_path());
    EXPECT_GE(d.size(), kTreeHeaderSize);
    auto h = DecodeTreeHeader(reinterpret_cast<const uint8_t*>(d.data()), tree_path());
    EXPECT_TRUE(h.ok()) << h.status().ToString();
    return h.ok() ? *h : TreeHeader{};
  }

  // Reopens and expects GetDataset to fail with Corruption mentioning every `needles`.
  void ExpectOpenCorruption(const std::vector<std::string>& needles) {
    auto db = Database::Open(dir_, TestOptions());
    ASSERT_TRUE(db.ok()) << db.status().ToString();
    auto ds = (*db)->GetDataset(kName);
    ASSERT_FALSE(ds.ok()) << "damaged dataset opened";
    const Status& st = ds.status();
    EXPECT_EQ(st.code(), StatusCode::kCorruption) << st.ToString();
    for (const std::string& n : needles) {
      EXPECT_TRUE(Contains(st.message(), n)) << "'" << st.message() << "' does not name " << n;
    }
    std::printf("[ error ] %s\n", st.ToString().c_str());
  }

  // A data block flipped: the dataset opens (only the header and checksum table are read
  // then), but a query reaching the block fails naming file and block, returns only correct
  // points before failing, keeps failing (the bad block is not cached), and Check reports it.
  void ExpectBlockCorruption(uint32_t block) {
    SCOPED_TRACE("block " + std::to_string(block));
    FlipByte(tree_path(), uint64_t{block} * 4096 + 100);
    auto db = Database::Open(dir_, TestOptions());
    ASSERT_TRUE(db.ok()) << db.status().ToString();
    auto ds = (*db)->GetDataset(kName);
    ASSERT_TRUE(ds.ok()) << ds.status().ToString();
    const std::string where = "block " + std::to_string(block) + ":";
    for (int attempt = 0; attempt < 2; ++attempt) {
      PointMap got;
      Status st = Collect(**ds, Everything(), &got);
      ASSERT_FALSE(st.ok()) << "a query over a damaged block succeeded with " << got.size()
                            << " points";
      EXPECT_EQ(st.code(), StatusCode::kCorruption) << st.ToString();
      EXPECT_TRUE(Contains(st.message(), tree_name_)) << st.message();
      EXPECT_TRUE(Contains(st.message(), where)) << st.message();
      for (const auto& [k, p] : got) {
        auto it = pristine_->find(k);
        ASSERT_TRUE(it != pristine_->end() && it->second == p)
            << "query returned a wrong point, id " << k.second;
      }
      if (attempt == 0)
        std::printf("[ error ] %s (after %zu good points)\n", st.ToString().c_str(), got.size());
    }
    auto problems = (*ds)->Check();
    ASSERT_FALSE(problems.empty()) << "Check() missed the damaged block";
    bool named = false;
    for (const std::string& p : problems) named |= Contains(p, tree_name_) && Contains(p, where);
    EXPECT_TRUE(named) << "no problem names " << tree_name_ << " " << where
                       << "; first: " << problems[0];
  }

  // Runs `body` in a child that exits without closing the database. Returns its exit code.
  template <typename Body>
  int InChild(Body body) {
    std::fflush(stdout);
    std::fflush(stderr);
    pid_t pid = ::fork();
    if (pid == 0) {
      int code = body();
      ::_exit(code);
    }
    int status = 0;
    while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
    }
    return WIFEXITED(status) ? WEXITSTATUS(status)
                             : 100 + (WIFSIGNALED(status) ? WTERMSIG(status) : 0);
  }

  // Commits `n` transactions of 8 points each into frames 1 and 2 (they stay in the
  // buffer T0, so only the log holds them) from a child that then exits without closing.
  // Returns the expected points of each transaction (ids continue after the bulk load).
  std::vector<PointMap> CommitInChild(int n) {
    std::vector<PointMap> txns(static_cast<size_t>(n));
    std::mt19937_64 rng(77);
    uint64_t id = kFramePoints + 1;
    std::vector<std::vector<Point>> batches;
    for (auto& t : txns) {
      std::vector<Point> pts;
      for (int i = 0; i < 8; ++i) pts.push_back(RandomPoint(rng, 1 + static_cast<uint32_t>(i % 2)));
      for (Point p : pts) {
        p.id = id++;
        t[{p.frame, p.id}] = p;
      }
      batches.push_back(std::move(pts));
    }
    int code = InChild([&]() -> int {
      auto db = Database::Open(dir_, TestOptions());
      if (!db.ok()) return 2;
      auto ds = (*db)->GetDataset(kName);
      if (!ds.ok()) return 3;
      for (auto& pts : batches) {
        Transaction txn;
        txn.Insert(pts);
        if (!(*ds)->Commit(txn).ok()) return 4;
      }
      ::_exit(0);  // without closing: a clean close would checkpoint the log away
    });
    EXPECT_EQ(code, 0);
    return txns;
  }

  struct Record {
    size_t offset, size;  // of the whole record, header included
  };
  std::vector<Record> WalRecords() {
    std::string d = ReadFile(wal_path());
    std::vector<Record> out;
    size_t pos = kWalHeader;
    while (pos + kWalRecordHeader <= d.size()) {
      uint32_t len = DecodeLE<uint32_t>(reinterpret_cast<const uint8_t*>(d.data()) + pos + 4);
      size_t size = kWalRecordHeader + len;
      if (pos + size > d.size()) break;
      out.push_back({pos, size});
      pos += size;
    }
    EXPECT_EQ(pos, d.size()) << "wal.log does not end on a record boundary";
    return out;
  }

  // Opens and expects exactly the pristine frame plus `txns`, with last_lsn = txns.size() + 1
  // (the pristine frame's bulk load took LSN 1).
  void ExpectCommitted(const std::vector<PointMap>& txns, const std::string& when) {
    SCOPED_TRACE(when);
    auto db = Database::Open(dir_, TestOptions());
    ASSERT_TRUE(db.ok()) << db.status().ToString();
    auto ds = (*db)->GetDataset(kName);
    ASSERT_TRUE(ds.ok()) << ds.status().ToString();
    PointMap want = *pristine_;
    for (const PointMap& t : txns) want.insert(t.begin(), t.end());
    PointMap got;
    Status st = Collect(**ds, Everything(), &got);
    ASSERT_TRUE(st.ok()) << st.ToString();
    EXPECT_EQ(got.size(), want.size());
    EXPECT_TRUE(got == want);
    EXPECT_EQ((*ds)->Info().last_lsn, txns.size() + 1);
    auto problems = (*ds)->Check();
    EXPECT_TRUE(problems.empty()) << problems[0];
  }

  static std::string* root_;
  static PointMap* pristine_;
  std::string dir_, tree_name_;
};

std::string* CorruptionTest::root_ = nullptr;
PointMap* CorruptionTest::pristine_ = nullptr;

TEST_F(CorruptionTest, PristineCopyIsIntact) {
  auto db = Database::Open(dir_, TestOptions());
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset(kName);
  ASSERT_TRUE(ds.ok()) << ds.status().ToString();
  PointMap got;
  ASSERT_TRUE(Collect(**ds, Everything(), &got).ok());
  EXPECT_TRUE(got == *pristine_);
  EXPECT_TRUE((*ds)->Check().empty());
}

// (a) One flipped byte in each kind of data block.
TEST_F(CorruptionTest, FlippedPointBlockFailsQueryNamingFileAndBlock) {
  TreeHeader h = Header();
  ASSERT_GT(h.level_count[0], 4 * h.points_per_block);
  ExpectBlockCorruption(h.level_start_block[0] + 3);  // full-resolution points
}

TEST_F(CorruptionTest, FlippedCoarseLevelBlockFailsQuery) {
  TreeHeader h = Header();
  ExpectBlockCorruption(h.level_start_block[h.levels - 1]);  // the coarsest level
}

TEST_F(CorruptionTest, FlippedNodeBlockFailsQuery) {
  TreeHeader h = Header();
  ASSERT_GT(h.node_block_count, 0u);
  ExpectBlockCorruption(h.node_block_start);  // the root's node block
}

TEST_F(CorruptionTest, FlippedDirectoryBlockFailsQuery) {
  TreeHeader h = Header();
  ASSERT_GT(h.dir_block_count, 1u);
  ExpectBlockCorruption(h.dir_block_start + 1);
}

TEST_F(CorruptionTest, FlippedTreeHeaderFailsOpen) {
  FlipByte(tree_path(), 20);
  ExpectOpenCorruption({tree_name_, "block 0"});
}

TEST_F(CorruptionTest, FlippedChecksumTableFailsOpen) {
  TreeHeader h = Header();
  FlipByte(tree_path(), uint64_t{h.crc_block_start} * 4096 + 8);
  ExpectOpenCorruption({tree_name_, "checksum"});
}

// (b) Truncated tree files.
TEST_F(CorruptionTest, TruncatedTreeFailsOpen) {
  uint64_t size = fs::file_size(tree_path());
  Truncate(tree_path(), size - 4096);
  ExpectOpenCorruption({tree_name_, "truncated"});
}

TEST_F(CorruptionTest, TreeTruncatedInsideHeaderFailsOpen) {
  Truncate(tree_path(), 100);
  ExpectOpenCorruption({tree_name_, "truncated"});
}

TEST_F(CorruptionTest, MissingTreeFailsOpenNamingIt) {
  fs::remove(tree_path());
  auto db = Database::Open(dir_, TestOptions());
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset(kName);
  ASSERT_FALSE(ds.ok());
  EXPECT_TRUE(Contains(ds.status().message(), tree_name_)) << ds.status().ToString();
}

// (c) Frame state file.
TEST_F(CorruptionTest, FlippedFrameStateFailsOpen) {
  uint64_t size = fs::file_size(fst_path());
  FlipByte(fst_path(), size / 2);
  ExpectOpenCorruption({"frames/00000000.fst", "checksum"});
}

TEST_F(CorruptionTest, TruncatedFrameStateFailsOpen) {
  Truncate(fst_path(), 10);
  ExpectOpenCorruption({"frames/00000000.fst", "truncated"});
}

// (f) MANIFEST.
TEST_F(CorruptionTest, FlippedManifestFailsOpen) {
  const std::string path = ds_dir() + "/MANIFEST";
  FlipByte(path, 14);
  ExpectOpenCorruption({"MANIFEST"});
}

TEST_F(CorruptionTest, TruncatedManifestFailsOpen) {
  const std::string path = ds_dir() + "/MANIFEST";
  Truncate(path, fs::file_size(path) - 3);
  ExpectOpenCorruption({"MANIFEST"});
}

// (d) Torn log tails: the last record incomplete after a crash mid-append.
TEST_F(CorruptionTest, LogTruncatedInsideLastRecordDropsOnlyThatCommit) {
  auto txns = CommitInChild(4);
  auto recs = WalRecords();
  ASSERT_EQ(recs.size(), 4u);
  Truncate(wal_path(), fs::file_size(wal_path()) - 5);
  txns.pop_back();
  ExpectCommitted(txns, "after a torn last record");
  // The torn bytes are cut off and the log goes on from there.
  {
    auto db = Database::Open(dir_, TestOptions());
    ASSERT_TRUE(db.ok());
    auto ds = (*db)->GetDataset(kName);
    ASSERT_TRUE(ds.ok());
    std::mt19937_64 rng(5);
    std::vector<Point> pts{RandomPoint(rng, 4), RandomPoint(rng, 4)};
    Transaction txn;
    txn.Insert(pts);
    auto c = (*ds)->Commit(txn);
    ASSERT_TRUE(c.ok()) << c.status().ToString();
    EXPECT_EQ(c->lsn, 5u);  // after the bulk load (1) and transactions 2, 3, 4 (torn)
    PointMap t;
    for (size_t i = 0; i < pts.size(); ++i) {
      pts[i].id = c->assigned_ids[i];
      t[{4, pts[i].id}] = pts[i];
    }
    txns.push_back(t);
  }
  ExpectCommitted(txns, "after a new commit on the repaired log");
}

TEST_F(CorruptionTest, LogRecordCutAfterItsHeaderIsTorn) {
  auto txns = CommitInChild(3);
  auto recs = WalRecords();
  ASSERT_EQ(recs.size(), 3u);
  Truncate(wal_path(), recs.back().offset + kWalRecordHeader + 3);
  txns.pop_back();
  ExpectCommitted(txns, "after a record cut 3 bytes into its payload");
}

TEST_F(CorruptionTest, HalfAppendedRecordAfterLastCommitIsIgnored) {
  auto txns = CommitInChild(3);
  auto recs = WalRecords();
  ASSERT_EQ(recs.size(), 3u);
  // A crash half-way through appending a fourth record: its first half is on disk.
  std::string d = ReadFile(wal_path());
  std::string last = d.substr(recs.back().offset, recs.back().size);
  WriteFile(wal_path(), d + last.substr(0, last.size() / 2));
  ExpectCommitted(txns, "after half a record of tail");
}

TEST_F(CorruptionTest, ShortGarbageTailIsIgnored) {
  auto txns = CommitInChild(3);
  std::string d = ReadFile(wal_path());
  WriteFile(wal_path(), d + std::string("\x13\x37garbage!", 10));
  ExpectCommitted(txns, "after 10 bytes of garbage");
}

// A complete last record with a bad checksum is indistinguishable from a torn write of it:
// the engine drops that record (documented in storage/wal.h) and keeps everything before.
TEST_F(CorruptionTest, BadChecksumInLastRecordDropsOnlyThatCommit) {
  auto txns = CommitInChild(3);
  auto recs = WalRecords();
  ASSERT_EQ(recs.size(), 3u);
  FlipByte(wal_path(), recs.back().offset + kWalRecordHeader + 40);
  txns.pop_back();
  ExpectCommitted(txns, "after a bad last record");
}

// (e) A damaged record with valid records after it is real corruption, not a torn tail.
TEST_F(CorruptionTest, CorruptRecordInMiddleOfLogFailsOpen) {
  CommitInChild(4);
  auto recs = WalRecords();
  ASSERT_EQ(recs.size(), 4u);
  FlipByte(wal_path(), recs[1].offset + kWalRecordHeader + 30);
  ExpectOpenCorruption({"wal.log", "offset " + std::to_string(recs[1].offset)});
}

// The length field is outside the record checksum. A middle record whose length was damaged
// so that it seems to run past the end of the file must not pass for a torn tail: the records
// after it were acknowledged, and reopening would silently drop them and cut them off the log.
// (wal.h: "a bad record with valid data after it is Corruption".)
TEST_F(CorruptionTest, CorruptLengthInMiddleRecordFailsOpen) {
  CommitInChild(4);
  auto recs = WalRecords();
  ASSERT_EQ(recs.size(), 4u);
  const uint64_t size_before = fs::file_size(wal_path());
  FlipByte(wal_path(), recs[1].offset + 6);  // third byte of record 2's length: +5.6 MB
  auto db = Database::Open(dir_, TestOptions());
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset(kName);
  if (ds.ok()) {
    EXPECT_FALSE(ds.ok()) << "opened with last_lsn " << (*ds)->Info().last_lsn
                          << ": acknowledged transactions 2..4 were dropped as a 'torn tail', "
                          << "and wal.log was cut from " << size_before << " to "
                          << fs::file_size(wal_path()) << " bytes";
  } else {
    EXPECT_EQ(ds.status().code(), StatusCode::kCorruption) << ds.status().ToString();
    EXPECT_TRUE(Contains(ds.status().message(), "wal.log")) << ds.status().ToString();
  }
}

TEST_F(CorruptionTest, CorruptLogHeaderFailsOpen) {
  CommitInChild(2);
  FlipByte(wal_path(), 2);
  ExpectOpenCorruption({"wal.log"});
}

// The log header's start sequence number (bytes 16..23) is covered by no checksum. Damaged, it
// contradicts the records after it (the first record is lsn 1, the header now claims the file
// starts at 0x5a000000000001); opening must not accept it and carry on from a bogus last_lsn.
TEST_F(CorruptionTest, CorruptLogStartSequenceNumberFailsOpen) {
  CommitInChild(2);
  FlipByte(wal_path(), 22);
  auto db = Database::Open(dir_, TestOptions());
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset(kName);
  if (ds.ok()) {
    EXPECT_FALSE(ds.ok()) << "opened with last_lsn " << (*ds)->Info().last_lsn
                          << " although the log's records are lsn 1 and 2";
  } else {
    EXPECT_EQ(ds.status().code(), StatusCode::kCorruption) << ds.status().ToString();
    EXPECT_TRUE(Contains(ds.status().message(), "wal.log")) << ds.status().ToString();
  }
}

// (g) The OS refuses. Root ignores permission bits, so the directories are replaced by regular
// files instead (ENOTDIR), which fails for root as well; the log write is made to fail with a
// file size limit (EFBIG).

// Expects the dataset (opened or not) to hold exactly `want` and to check clean.
void ExpectIntact(Dataset& ds, const PointMap& want) {
  PointMap got;
  Status st = Collect(ds, Everything(), &got);
  ASSERT_TRUE(st.ok()) << st.ToString();
  EXPECT_EQ(got.size(), want.size());
  EXPECT_TRUE(got == want);
  auto problems = ds.Check();
  EXPECT_TRUE(problems.empty()) << problems[0];
}

// Moves `path` aside and puts a regular file in its place; undone by Restore.
void ReplaceDirWithFile(const std::string& path) {
  fs::rename(path, path + ".aside");
  WriteFile(path, "not a directory");
}
void Restore(const std::string& path) {
  fs::remove(path);
  fs::rename(path + ".aside", path);
}

TEST_F(CorruptionTest, BulkLoadWithUnwritableFramesDirFailsCleanly) {
  auto db = Database::Open(dir_, TestOptions());
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset(kName);
  ASSERT_TRUE(ds.ok());
  std::mt19937_64 rng(8);
  std::vector<Point> pts;
  for (int i = 0; i < 5000; ++i) pts.push_back(RandomPoint(rng, 5));

  ReplaceDirWithFile(ds_dir() + "/frames");
  auto r = (*ds)->BulkLoad(5, pts);
  ASSERT_FALSE(r.ok()) << "bulk load succeeded without a frames directory";
  EXPECT_EQ(r.status().code(), StatusCode::kIOError) << r.status().ToString();
  EXPECT_TRUE(Contains(r.status().message(), "frames/00000005.fst")) << r.status().ToString();
  EXPECT_TRUE(Contains(r.status().message(), std::strerror(ENOTDIR))) << r.status().ToString();
  std::printf("[ error ] %s\n", r.status().ToString().c_str());
  Restore(ds_dir() + "/frames");

  // Nothing of the failed load is visible or left behind.
  EXPECT_EQ((*ds)->Info().point_count, kFramePoints);
  ExpectIntact(**ds, *pristine_);
  EXPECT_EQ(FilesIn(ds_dir() + "/trees", ".kdt").size(), 1u) << "the failed load's tree remains";
  // Once the directory is back the same load succeeds, and survives a reopen.
  auto again = (*ds)->BulkLoad(5, pts);
  ASSERT_TRUE(again.ok()) << again.status().ToString();
  EXPECT_EQ((*ds)->Info().point_count, kFramePoints + pts.size());
  ds->reset();
  db->reset();
  auto db2 = Database::Open(dir_, TestOptions());
  ASSERT_TRUE(db2.ok());
  auto ds2 = (*db2)->GetDataset(kName);
  ASSERT_TRUE(ds2.ok()) << ds2.status().ToString();
  EXPECT_EQ((*ds2)->Info().point_count, kFramePoints + pts.size());
  EXPECT_TRUE((*ds2)->Check().empty());
}

TEST_F(CorruptionTest, BulkLoadWithUnwritableTreesDirFailsCleanly) {
  auto db = Database::Open(dir_, TestOptions());
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset(kName);
  ASSERT_TRUE(ds.ok());
  std::mt19937_64 rng(9);
  std::vector<Point> pts;
  for (int i = 0; i < 3000; ++i) pts.push_back(RandomPoint(rng, 6));

  // Move the trees aside: the open dataset keeps its tree file open, so queries still work.
  ReplaceDirWithFile(ds_dir() + "/trees");
  auto r = (*ds)->BulkLoad(6, pts);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kIOError) << r.status().ToString();
  EXPECT_TRUE(Contains(r.status().message(), "trees/")) << r.status().ToString();
  std::printf("[ error ] %s\n", r.status().ToString().c_str());

  // A commit whose buffer overflows still commits (the log has it); the merger's tree build
  // fails and is retried later.
  std::vector<Point> more;
  for (int i = 0; i < 100; ++i) more.push_back(RandomPoint(rng, 7));
  Transaction txn;
  txn.Insert(more);
  auto c = (*ds)->Commit(txn);
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  PointMap want = *pristine_;
  for (size_t i = 0; i < more.size(); ++i) {
    Point p = more[i];
    p.id = c->assigned_ids[i];
    want[{7, p.id}] = p;
  }
  EXPECT_FALSE((*ds)->WaitForMerges().ok()) << "the merger cannot have written a tree";
  Restore(ds_dir() + "/trees");
  ExpectIntact(**ds, want);
  ds->reset();
  db->reset();
  auto db2 = Database::Open(dir_, TestOptions());
  ASSERT_TRUE(db2.ok());
  auto ds2 = (*db2)->GetDataset(kName);
  ASSERT_TRUE(ds2.ok()) << ds2.status().ToString();
  ExpectIntact(**ds2, want);
  // The deferred merge happens, at the latest when the dataset is opened again.
  ASSERT_TRUE((*ds2)->WaitForMerges().ok());
  EXPECT_EQ((*ds2)->Stats().buffered_points, 0u) << "the deferred merge never happened";
  EXPECT_EQ(FilesIn(ds_dir() + "/trees", ".kdt").size(), 2u);
  Transaction one;
  one.Insert({RandomPoint(rng, 7)});
  auto c2 = (*ds2)->Commit(one);
  ASSERT_TRUE(c2.ok()) << c2.status().ToString();
  EXPECT_EQ((*ds2)->Stats().buffered_points, 1u);
  EXPECT_TRUE((*ds2)->Check().empty());
}


TEST_F(CorruptionTest, LogWriteFailureLeavesNoTraceOfTheTransaction) {
  // In a child (the limit is per process): the log may grow by at most 4 KiB; a transaction
  // of 100 points (6.4 KB) fails with EFBIG, a smaller one after it must still commit.
  int pipefd[2];
  ASSERT_EQ(::pipe(pipefd), 0);
  std::mt19937_64 rng(11);
  std::vector<Point> big, small;
  for (int i = 0; i < 100; ++i) big.push_back(RandomPoint(rng, 3));
  for (int i = 0; i < 10; ++i) small.push_back(RandomPoint(rng, 3));
  int code = InChild([&]() -> int {
    ::close(pipefd[0]);
    auto db = Database::Open(dir_, TestOptions());
    if (!db.ok()) return 2;
    auto ds = (*db)->GetDataset(kName);
    if (!ds.ok()) return 3;
    ::signal(SIGXFSZ, SIG_IGN);
    rlimit lim{};
    lim.rlim_cur = lim.rlim_max = fs::file_size(wal_path()) + 4096;
    if (::setrlimit(RLIMIT_FSIZE, &lim) != 0) return 4;
    Transaction t1;
    t1.Insert(big);
    auto c1 = (*ds)->Commit(t1);
    std::string report = c1.ok() ? "ok" : c1.status().ToString();
    Transaction t2;
    t2.Insert(small);
    auto c2 = (*ds)->Commit(t2);
    report += "\n" + (c2.ok() ? "lsn " + std::to_string(c2->lsn) : c2.status().ToString());
    if (::write(pipefd[1], report.data(), report.size()) < 0) return 5;
    ::close(pipefd[1]);
    ::_exit(0);  // without closing: recovery must replay only the second transaction
  });
  ::close(pipefd[1]);
  std::string report;
  char buf[512];
  for (ssize_t n; (n = ::read(pipefd[0], buf, sizeof(buf))) > 0;)
    report.append(buf, static_cast<size_t>(n));
  ::close(pipefd[0]);
  ASSERT_EQ(code, 0);
  std::printf("[ child ] %s\n", report.c_str());
  auto nl = report.find('\n');
  ASSERT_NE(nl, std::string::npos);
  std::string first = report.substr(0, nl), second = report.substr(nl + 1);
  EXPECT_TRUE(Contains(first, "IOError")) << first;
  EXPECT_TRUE(Contains(first, "wal.log")) << first;
  EXPECT_TRUE(Contains(first, std::strerror(EFBIG))) << first;
  // (LSN 1 is the pristine frame's bulk load.)
  EXPECT_EQ(second, "lsn 2") << "the failed transaction must not use up a sequence number";

  auto db = Database::Open(dir_, TestOptions());
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset(kName);
  ASSERT_TRUE(ds.ok()) << ds.status().ToString();
  PointMap got;
  ASSERT_TRUE(Collect(**ds, Everything(), &got).ok());
  EXPECT_EQ(got.size(), kFramePoints + small.size());
  size_t in_frame3 = 0;
  for (const auto& [k, p] : got) {
    if (k.first != 3) continue;
    ++in_frame3;
    EXPECT_TRUE(std::find_if(small.begin(), small.end(),
                             [&](const Point& s) {
                               return s.x == p.x && s.y == p.y && s.z == p.z;
                             }) != small.end())
        << "a point of the failed transaction survived";
  }
  EXPECT_EQ(in_frame3, small.size());
  EXPECT_EQ((*ds)->Info().last_lsn, 2u);
  EXPECT_TRUE((*ds)->Check().empty());
}

}  // namespace
}  // namespace hvdb
