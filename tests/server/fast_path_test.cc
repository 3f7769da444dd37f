// The served path's transports (server/session_stream.cc, protocol/shm.h, client/client.cc): the
// same queries over TCP (records in frame attachments, point columns, Draco) and over the Unix
// socket (with and without the shared-memory ring) give the same points; the ring's guarantees
// hold against clients that misbehave (never release a slot, release one they do not hold, die
// holding slots). A real hvdb-server process throughout.
#include <signal.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <random>
#include <thread>

#include "client/client.h"
#include "protocol/shm.h"
#include "storage/coding.h"
#include "tests/server/query_util.h"
#include "tests/server/server_process.h"
#include "tests/storage/test_util.h"

namespace hvdb {
namespace {

using client::Connection;
using testing::All;
using testing::RandomPoints;
using testing::ServerProcess;
using testing::TempDir;

constexpr double kFps = 10.0;

enum class Transport { kTcpRecords, kTcpColumns, kUnixRecords, kUnixShm, kLoopbackAuto };

std::string Name(Transport t) {
  switch (t) {
    case Transport::kTcpRecords: return "TcpRecords";
    case Transport::kTcpColumns: return "TcpColumns";
    case Transport::kUnixRecords: return "UnixRecords";
    case Transport::kUnixShm: return "UnixShm";
    case Transport::kLoopbackAuto: return "LoopbackAuto";
  }
  return "?";
}

// A server on TCP and on a Unix socket, with a dataset of a few frames.
class FastPathFixture {
 public:
  FastPathFixture() {
    sock_ = dir_.path() + "/hvdb.sock";
    server_ = std::make_unique<ServerProcess>(dir_.path() + "/data",
                                              std::vector<std::string>{"--listen", "unix:" + sock_});
  }
  client::Options Opts(Transport t) const {
    client::Options o;
    o.port = server_->port();
    o.request_timeout = std::chrono::milliseconds(30000);
    o.prefer_local = t == Transport::kLoopbackAuto;
    o.columns = t == Transport::kTcpColumns;
    if (t == Transport::kUnixRecords || t == Transport::kUnixShm) o.unix_path = sock_;
    o.shm = t != Transport::kUnixRecords;
    return o;
  }
  // An empty dataset at kFps.
  static void CreateDataset(Connection& c, const std::string& name) {
    DatasetInfo info;
    info.name = name;
    info.fps = kFps;
    ASSERT_TRUE(c.CreateDataset(info).ok());
  }
  std::unique_ptr<Connection> Connect(Transport t) const {
    auto c = Connection::Connect(Opts(t));
    EXPECT_TRUE(c.ok()) << c.status().ToString();
    return c.ok() ? std::move(c).value() : nullptr;
  }
  TempDir dir_;
  std::string sock_;
  std::unique_ptr<ServerProcess> server_;
};

std::vector<Point> SortedById(std::vector<Point> v) {
  std::sort(v.begin(), v.end(), [](const Point& a, const Point& b) {
    return a.frame != b.frame ? a.frame < b.frame : a.id < b.id;
  });
  return v;
}

class ServerTransportTest : public ::testing::TestWithParam<Transport> {
 protected:
  void SetUp() override {
    ASSERT_TRUE(fx_.server_->running());
    auto c = fx_.Connect(Transport::kTcpColumns);
    ASSERT_NE(c, nullptr);
    FastPathFixture::CreateDataset(*c, "v");
    std::mt19937_64 rng(21);
    for (uint32_t f = 0; f < 3; ++f) {
      auto pts = RandomPoints(rng, 40000, f);
      for (size_t i = 0; i < pts.size(); ++i) pts[i].label = static_cast<uint32_t>(1u << (i % 3));
      ASSERT_TRUE(c->Ingest("v", f, pts).ok());
    }
  }
  FastPathFixture fx_;
};

TEST_P(ServerTransportTest, QueriesAgreeWithPointColumns) {
  auto ref = fx_.Connect(Transport::kTcpColumns);
  auto c = fx_.Connect(GetParam());
  ASSERT_NE(c, nullptr);
  const std::string t = c->transport();
  switch (GetParam()) {
    case Transport::kUnixShm:
    case Transport::kLoopbackAuto:
      EXPECT_EQ(t, "unix " + fx_.sock_ + " + shared memory");
      break;
    case Transport::kUnixRecords: EXPECT_EQ(t, "unix " + fx_.sock_); break;
    default: EXPECT_EQ(t.rfind("tcp ", 0), 0u) << t;
  }
  Window all = testing::EverythingWindow();
  Window box = all;
  box.lo[0] = -2;
  box.hi[0] = 3;
  Slice s;
  s.normal = {0, 0, 0, 1};
  s.offset = 1 / kFps;
  s.thickness = 0.01;
  struct Case {
    const char* name;
    Region r;
    QueryOptions o;
  };
  QueryOptions plain, lod, prog, labels, tiny;
  lod.lod = 2;
  prog.progressive = true;
  prog.batch_points = 3000;
  labels.label_mask = 2;
  tiny.batch_points = 1;
  for (const Case& k : {Case{"everything", all, plain}, Case{"box", box, plain},
                        Case{"slice", s, plain}, Case{"lod 2", all, lod},
                        Case{"progressive", box, prog}, Case{"label mask", all, labels},
                        Case{"batches of one bucket level", testing::FrameWindow(1, kFps), tiny}}) {
    SCOPED_TRACE(k.name);
    auto want = All(*ref, "v", k.r, k.o);
    auto got = All(*c, "v", k.r, k.o);
    ASSERT_FALSE(want.empty());
    EXPECT_EQ(got.size(), want.size());
    EXPECT_TRUE(SortedById(got) == SortedById(want));  // every field, bit for bit
  }
}

TEST_P(ServerTransportTest, PipelinedQueriesInterleave) {
  // Two queries in flight at once: batches of one are kept aside (with their records or ring
  // slots) while the other is read.
  auto c = fx_.Connect(GetParam());
  ASSERT_NE(c, nullptr);
  QueryOptions o;
  o.batch_points = 2000;
  auto a = c->Query("v", testing::FrameWindow(0, kFps), o);
  auto b = c->Query("v", testing::FrameWindow(2, kFps), o);
  ASSERT_TRUE(a.ok() && b.ok());
  std::vector<Point> pa, pb;
  Batch batch;
  bool more_a = true, more_b = true;
  while (more_a || more_b) {
    if (more_b) {
      auto r = (*b)->Next(&batch);
      ASSERT_TRUE(r.ok()) << r.status().ToString();
      more_b = *r;
      if (more_b) pb.insert(pb.end(), batch.points.begin(), batch.points.end());
    }
    if (more_a) {
      auto r = (*a)->Next(&batch);
      ASSERT_TRUE(r.ok()) << r.status().ToString();
      more_a = *r;
      if (more_a) pa.insert(pa.end(), batch.points.begin(), batch.points.end());
    }
  }
  EXPECT_EQ(pa.size(), 40000u);
  EXPECT_EQ(pb.size(), 40000u);
  for (const Point& p : pa) ASSERT_EQ(p.frame, 0u);
  for (const Point& p : pb) ASSERT_EQ(p.frame, 2u);
  EXPECT_TRUE(c->Ping().ok());
}

TEST_P(ServerTransportTest, ViewsAreTheSameRecordsWithoutACopy) {
  auto c = fx_.Connect(GetParam());
  ASSERT_NE(c, nullptr);
  auto want = All(*c, "v", testing::EverythingWindow());
  auto q = c->Query("v", testing::EverythingWindow());
  ASSERT_TRUE(q.ok());
  std::vector<Point> got;
  client::BatchView v;
  for (;;) {
    auto more = (*q)->NextView(&v);
    ASSERT_TRUE(more.ok()) << more.status().ToString();
    if (!*more) break;
    got.insert(got.end(), v.points.begin(), v.points.end());
  }
  EXPECT_TRUE(got == want);
}

TEST_P(ServerTransportTest, CancelMidStreamKeepsTheConnection) {
  auto c = fx_.Connect(GetParam());
  ASSERT_NE(c, nullptr);
  // A frame of 32 MB: more than the ring, the flow control's queue and both sockets' kernel
  // buffers together, so that the query cannot have ended before the cancel arrives.
  std::mt19937_64 rng(24);
  const size_t big = 500000;
  ASSERT_EQ(*c->Ingest("v", 3, RandomPoints(rng, big, 3)), big);
  for (int round = 0; round < 3; ++round) {
    QueryOptions o;
    o.batch_points = 500;
    auto q = c->Query("v", testing::FrameWindow(3, kFps), o);
    ASSERT_TRUE(q.ok());
    Batch b;
    ASSERT_TRUE(*(*q)->Next(&b));
    ASSERT_TRUE((*q)->Cancel().ok());
    Status end;
    size_t after = 0;
    for (;;) {
      auto more = (*q)->Next(&b);
      if (!more.ok()) {
        end = more.status();
        break;
      }
      if (!*more) break;
      after += b.points.size();
    }
    EXPECT_EQ(end.code(), StatusCode::kCancelled);
    EXPECT_LT(after, big - 500);
  }
  // Streams dropped half-way cancel themselves; every ring slot comes back.
  for (int i = 0; i < 40; ++i) {
    auto q = c->Query("v", testing::EverythingWindow());
    ASSERT_TRUE(q.ok());
    Batch b;
    ASSERT_TRUE(*(*q)->Next(&b));
  }
  EXPECT_EQ(All(*c, "v", testing::EverythingWindow()).size(), 120000u + big);
}

INSTANTIATE_TEST_SUITE_P(Server, ServerTransportTest,
                         ::testing::Values(Transport::kTcpRecords, Transport::kTcpColumns,
                                           Transport::kUnixRecords, Transport::kUnixShm,
                                           Transport::kLoopbackAuto),
                         [](const auto& p) { return Name(p.param); });

// ---- Misbehaving clients, on raw sockets. ----

// A raw Unix-socket client that asks for the ring and speaks frames by hand.
class RawUnixClient {
 public:
  explicit RawUnixClient(const std::string& path) {
    fd_ = ::socket(AF_UNIX, SOCK_STREAM, 0);
    sockaddr_un a{};
    a.sun_family = AF_UNIX;
    std::snprintf(a.sun_path, sizeof(a.sun_path), "%s", path.c_str());
    connected_ = ::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof(a)) == 0;
    timeval tv{5, 0};
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
  }
  ~RawUnixClient() {
    ring_.reset();
    ::close(fd_);
  }
  bool connected() const { return connected_; }
  void Write(const std::string& s) { (void)!::send(fd_, s.data(), s.size(), MSG_NOSIGNAL); }
  // Sends a Hello asking for the ring and maps it; false if there is none.
  bool Handshake() {
    wire::Hello h;
    h.set_protocol_version(wire::kProtocolVersion);
    h.add_capabilities("shm");
    Write(wire::Frame(h));
    uint8_t header[4];
    int fd = -1;
    if (!wire::RecvWithFd(fd_, header, 4, &fd, std::chrono::seconds(5)).ok()) return false;
    uint32_t len = DecodeLE<uint32_t>(header);
    std::string payload(len, '\0');
    if (!ReadExact(payload.data(), len)) return false;
    wire::HelloReply reply;
    if (!reply.ParseFromString(payload) || fd < 0) return false;
    auto ring = wire::ShmRing::Map(fd, reply.shm_slots(), reply.shm_slot_bytes());
    if (!ring.ok()) return false;
    ring_ = std::move(ring).value();
    return true;
  }
  bool ReadExact(char* p, size_t n) {
    while (n > 0) {
      ssize_t r = ::recv(fd_, p, n, 0);
      if (r <= 0) return false;
      p += r;
      n -= static_cast<size_t>(r);
    }
    return true;
  }
  // The next frame's response; false on close or timeout.
  bool Read(wire::Response* r) {
    uint8_t header[4];
    if (!ReadExact(reinterpret_cast<char*>(header), 4)) return false;
    uint32_t w = DecodeLE<uint32_t>(header);
    uint32_t att = 0;
    if (w & wire::kAttachmentFlag) {
      if (!ReadExact(reinterpret_cast<char*>(header), 4)) return false;
      att = DecodeLE<uint32_t>(header);
    }
    std::string payload((w & ~wire::kAttachmentFlag) + att, '\0');
    if (!ReadExact(payload.data(), payload.size())) return false;
    return r->ParseFromArray(payload.data(), static_cast<int>(payload.size() - att));
  }
  wire::ShmRing* ring() { return ring_.get(); }
  int fd() const { return fd_; }

 private:
  int fd_;
  bool connected_ = false;
  std::unique_ptr<wire::ShmRing> ring_;
};

std::string QueryFrame(uint64_t id, const std::string& ds, uint32_t batch_points) {
  wire::Request q;
  q.set_id(id);
  q.mutable_query()->set_dataset(ds);
  q.mutable_query()->set_encoding(wire::RECORDS);
  q.mutable_query()->set_batch_points(batch_points);
  auto* w = q.mutable_query()->mutable_region()->mutable_window();
  for (int i = 0; i < 4; ++i) {
    w->add_lo(-1e9);
    w->add_hi(1e9);
  }
  return wire::Frame(q);
}

class ServerFastPathTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(fx_.server_->running());
    c_ = fx_.Connect(Transport::kTcpRecords);
    ASSERT_NE(c_, nullptr);
    FastPathFixture::CreateDataset(*c_, "s");
    std::mt19937_64 rng(22);
    for (uint32_t f = 0; f < 4; ++f) ASSERT_TRUE(c_->Ingest("s", f, RandomPoints(rng, 100000, f)).ok());
  }
  FastPathFixture fx_;
  std::unique_ptr<Connection> c_;
};

TEST_F(ServerFastPathTest, AClientThatNeverReleasesHoldsOnlyItsRing) {
  // Warm the block cache first: what grows afterwards is what the connections hold.
  ASSERT_EQ(All(*c_, "s", testing::EverythingWindow()).size(), 400000u);
  long before = fx_.server_->RssKib();
  RawUnixClient hog(fx_.sock_);
  ASSERT_TRUE(hog.connected());
  ASSERT_TRUE(hog.Handshake());
  const uint32_t slots = hog.ring()->slots();
  hog.Write(QueryFrame(1, "s", 16384));
  // The server fills every slot, then waits: no more batches come, however long we wait.
  uint32_t batches = 0;
  wire::Response r;
  timeval tv{1, 0};
  ::setsockopt(hog.fd(), SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
  while (hog.Read(&r)) {
    ASSERT_TRUE(r.has_batch()) << r.DebugString();
    EXPECT_GT(r.batch().shm_slot(), 0u);
    ++batches;
  }
  EXPECT_EQ(batches, slots);
  // The records in the ring are real points of the dataset.
  const auto* p = reinterpret_cast<const Point*>(hog.ring()->slot(0));
  EXPECT_LT(p->frame, 4u);
  // Everyone else is served meanwhile, on either path, and the server's memory is bounded by
  // the rings (16 MiB each, the hog's and the other local client's), not the 25 MB result.
  auto local = fx_.Connect(Transport::kUnixShm);
  ASSERT_NE(local, nullptr);
  EXPECT_EQ(All(*local, "s", testing::FrameWindow(2, kFps)).size(), 100000u);
  EXPECT_EQ(All(*c_, "s", testing::FrameWindow(3, kFps)).size(), 100000u);
  long during = fx_.server_->RssKib();
  EXPECT_LT(during - before, 40 * 1024) << "before " << before << " KiB, during " << during;
  // Releasing one slot lets exactly one more batch through.
  wire::Request rel;
  rel.mutable_release()->add_slots(0);
  hog.Write(wire::Frame(rel));
  ASSERT_TRUE(hog.Read(&r));
  EXPECT_EQ(r.batch().shm_slot(), 1u);
  EXPECT_FALSE(hog.Read(&r));
}

TEST_F(ServerFastPathTest, AQueryReadAfterAnotherDoesNotWaitForItsSlots) {
  // Two queries on one connection, the second read to its end before the first is touched:
  // the first's batches take every ring slot (kept aside by the client, unreleased), so the
  // second gets its records through the socket instead of waiting for a slot forever.
  auto c = fx_.Connect(Transport::kUnixShm);
  ASSERT_NE(c, nullptr);
  QueryOptions o;
  o.batch_points = 4096;
  auto first = c->Query("s", testing::EverythingWindow(), o);
  ASSERT_TRUE(first.ok());
  std::this_thread::sleep_for(std::chrono::milliseconds(200));  // let it fill the ring
  auto second = c->Query("s", testing::FrameWindow(1, kFps), o);
  ASSERT_TRUE(second.ok());
  EXPECT_EQ(testing::Drain(**second).size(), 100000u);
  EXPECT_EQ(testing::Drain(**first).size(), 400000u);
}

TEST_F(ServerFastPathTest, ReleasingASlotNotHeldIsMalformed) {
  RawUnixClient c(fx_.sock_);
  ASSERT_TRUE(c.Handshake());
  wire::Request rel;
  rel.mutable_release()->add_slots(3);
  c.Write(wire::Frame(rel));
  wire::Response r;
  ASSERT_TRUE(c.Read(&r));
  EXPECT_EQ(r.error().code(), wire::MALFORMED);
  EXPECT_NE(r.error().message().find("slot 3"), std::string::npos) << r.error().message();
  EXPECT_FALSE(c.Read(&r));  // closed
  EXPECT_TRUE(c_->Ping().ok());
}

TEST_F(ServerFastPathTest, AttachmentsFromClientsAndOldVersionsAreRefused) {
  {
    RawUnixClient c(fx_.sock_);
    wire::Hello h;
    h.set_protocol_version(1);
    c.Write(wire::Frame(h));
    wire::Response r;
    ASSERT_TRUE(c.Read(&r));
    EXPECT_EQ(r.error().code(), wire::UNSUPPORTED);
    EXPECT_NE(r.error().message().find("version 2"), std::string::npos) << r.error().message();
  }
  {
    RawUnixClient c(fx_.sock_);
    ASSERT_TRUE(c.Handshake());
    std::string f(8, '\0');
    EncodeLE(reinterpret_cast<uint8_t*>(f.data()), 2u | wire::kAttachmentFlag);
    EncodeLE(reinterpret_cast<uint8_t*>(f.data()) + 4, 64u);
    c.Write(f + std::string(2 + 64, '\0'));
    wire::Response r;
    ASSERT_TRUE(c.Read(&r));
    EXPECT_EQ(r.error().code(), wire::MALFORMED);
  }
  EXPECT_TRUE(c_->Ping().ok());
}

TEST_F(ServerFastPathTest, ClientsKilledWhileHoldingSlotsLeakNothing) {
  // Warm up: one full local read, so that what stays resident is measured after it.
  auto local = fx_.Connect(Transport::kUnixShm);
  ASSERT_EQ(All(*local, "s", testing::EverythingWindow()).size(), 400000u);
  long before = fx_.server_->RssKib();
  for (int i = 0; i < 12; ++i) {
    pid_t pid = ::fork();
    if (pid == 0) {
      // The child: the fast path, a query half read, then death by SIGKILL.
      client::Options o = fx_.Opts(Transport::kUnixShm);
      auto c = Connection::Connect(o);
      if (!c.ok()) ::_exit(3);
      auto q = (*c)->Query("s", testing::EverythingWindow());
      if (!q.ok()) ::_exit(4);
      client::BatchView v;
      for (int k = 0; k < 3; ++k) {
        if (!(*q)->NextView(&v).ok()) ::_exit(5);
      }
      ::raise(SIGKILL);
      ::_exit(6);
    }
    int status = 0;
    ASSERT_EQ(::waitpid(pid, &status, 0), pid);
    ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL) << "child status " << status;
  }
  // The server noticed every death: only our two connections stay open.
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  auto st = c_->Stats();
  ASSERT_TRUE(st.ok());
  EXPECT_EQ(st->connections_open(), 2u);
  long after = fx_.server_->RssKib();
  EXPECT_LT(after - before, 32 * 1024) << "before " << before << " KiB, after " << after;
  EXPECT_EQ(All(*local, "s", testing::EverythingWindow()).size(), 400000u);
}

TEST_F(ServerFastPathTest, EveryRequestKindOverTheUnixSocket) {
  auto c = fx_.Connect(Transport::kUnixShm);
  ASSERT_NE(c, nullptr);
  ASSERT_TRUE(c->Ping().ok());
  DatasetInfo info;
  info.name = "u";
  info.fps = kFps;
  ASSERT_TRUE(c->CreateDataset(info).ok());
  auto names = c->ListDatasets();
  ASSERT_TRUE(names.ok());
  EXPECT_EQ(names->size(), 2u);
  std::mt19937_64 rng(23);
  ASSERT_EQ(*c->Ingest("u", 0, RandomPoints(rng, 30000, 0)), 30000u);
  EXPECT_EQ(c->Describe("u")->point_count, 30000u);
  Window half = testing::EverythingWindow();
  half.hi[0] = 0;
  Transaction t;
  Selection sel;
  sel.region = half;
  t.DeleteSelection(sel);
  auto commit = c->Commit("u", t);
  ASSERT_TRUE(commit.ok()) << commit.status().ToString();
  EXPECT_EQ(All(*c, "u", testing::EverythingWindow()).size(), 30000u - commit->removed);
  ASSERT_TRUE(c->Revert("u", commit->lsn).ok());
  EXPECT_EQ(All(*c, "u", testing::EverythingWindow()).size(), 30000u);
  auto st = c->Stats("u");
  ASSERT_TRUE(st.ok());
  EXPECT_EQ(st->dataset().points(), 30000u);
  wire::Render render;
  render.set_dataset("u");
  EXPECT_EQ(c->Render(render).status().code(), StatusCode::kInvalidArgument);  // no camera
  EXPECT_EQ(c->Describe("nope").status().code(), StatusCode::kNotFound);
  ASSERT_TRUE(c->DropDataset("u").ok());
}

TEST(ServerUnixSocketTest, TokensAndRolesHoldOnTheUnixSocket) {
  TempDir dir;
  const std::string tokens = dir.path() + "/tokens", sock = dir.path() + "/s.sock";
  {
    std::ofstream(tokens) << "readonly-0123456789abcdef ro\nreadwrite-0123456789abcdef rw\n";
  }
  ServerProcess server(dir.path() + "/data", {"--token-file", tokens, "--listen", "unix:" + sock});
  ASSERT_TRUE(server.running());
  client::Options o;
  o.unix_path = sock;
  auto none = Connection::Connect(o);
  ASSERT_FALSE(none.ok());
  EXPECT_EQ(none.status().code(), StatusCode::kPermissionDenied);
  o.token = "readwrite-0123456789abcdef";
  auto rw = Connection::Connect(o);
  ASSERT_TRUE(rw.ok()) << rw.status().ToString();
  DatasetInfo info;
  info.name = "a";
  ASSERT_TRUE((*rw)->CreateDataset(info).ok());
  o.token = "readonly-0123456789abcdef";
  auto ro = Connection::Connect(o);
  ASSERT_TRUE(ro.ok());
  EXPECT_EQ((*ro)->transport(), "unix " + sock + " + shared memory");
  EXPECT_TRUE((*ro)->Describe("a").ok());
  EXPECT_EQ((*ro)->DropDataset("a").code(), StatusCode::kPermissionDenied);
  // A loopback TCP client with a token moves to the socket with the same token.
  client::Options tcp;
  tcp.port = server.port();
  tcp.token = "readonly-0123456789abcdef";
  auto moved = Connection::Connect(tcp);
  ASSERT_TRUE(moved.ok());
  EXPECT_EQ((*moved)->transport(), "unix " + sock + " + shared memory");
  EXPECT_EQ((*moved)->role(), wire::ROLE_READ_ONLY);
}

TEST(ServerUnixSocketTest, StaleSocketIsReplacedLiveOneIsNot) {
  TempDir dir;
  const std::string sock = dir.path() + "/s.sock";
  {
    ServerProcess a(dir.path() + "/a", {"--listen", "unix:" + sock});
    ASSERT_TRUE(a.running());
    // A second server on the same live socket refuses to start, saying why.
    ServerProcess b(dir.path() + "/b", {"--listen", "unix:" + sock});
    EXPECT_FALSE(b.running());
    a.Stop(SIGKILL);  // leaves the socket file behind
  }
  ServerProcess c(dir.path() + "/a", {"--listen", "unix:" + sock});
  ASSERT_TRUE(c.running());
  client::Options o;
  o.unix_path = sock;
  auto conn = Connection::Connect(o);
  ASSERT_TRUE(conn.ok()) << conn.status().ToString();
  EXPECT_TRUE((*conn)->Ping().ok());
}

}  // namespace
}  // namespace hvdb
