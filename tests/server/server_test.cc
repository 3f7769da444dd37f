// Integration tests: a real hvdb-server process on an ephemeral loopback port, driven through
// the client library (and raw sockets for malformed input).
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>

#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <map>
#include <random>
#include <set>
#include <thread>

#include "client/client.h"
#include "codec/codec.h"
#include "protocol/wire.h"
#include "storage/coding.h"
#include "tests/edit/scene.h"
#include "tests/server/frames.h"
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

Window Everything() { return testing::EverythingWindow(); }

Window FrameWindow(uint32_t f) { return testing::FrameWindow(f, kFps); }

client::Options Opts(uint16_t port) {
  client::Options o;
  o.port = port;
  o.request_timeout = std::chrono::milliseconds(30000);
  return o;
}

std::unique_ptr<Connection> Connect(uint16_t port, const std::string& token = "") {
  auto o = Opts(port);
  o.token = token;
  auto c = Connection::Connect(o);
  EXPECT_TRUE(c.ok()) << c.status().ToString();
  return c.ok() ? std::move(c).value() : nullptr;
}

std::set<uint64_t> Ids(const std::vector<Point>& pts) {
  std::set<uint64_t> s;
  for (const Point& p : pts) s.insert(p.id);
  return s;
}

class ServerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    data_ = dir_.path() + "/data";
    server_ = std::make_unique<ServerProcess>(data_);
    ASSERT_TRUE(server_->running()) << "hvdb-server did not start";
  }
  std::shared_ptr<Connection> NewDataset(const std::string& name) {
    auto c = Connect(server_->port());
    DatasetInfo info;
    info.name = name;
    info.fps = kFps;
    auto r = c->CreateDataset(info);
    EXPECT_TRUE(r.ok()) << r.status().ToString();
    return std::shared_ptr<Connection>(std::move(c));
  }
  TempDir dir_;
  std::string data_;
  std::unique_ptr<ServerProcess> server_;
};

TEST_F(ServerTest, EveryRequestKind) {
  auto c = NewDataset("video");
  ASSERT_TRUE(c->Ping().ok());
  auto list = c->ListDatasets();
  ASSERT_TRUE(list.ok());
  EXPECT_EQ(*list, std::vector<std::string>{"video"});
  std::mt19937_64 rng(1);
  auto f0 = RandomPoints(rng, 20000, 0);
  auto f1 = RandomPoints(rng, 30000, 1);
  ASSERT_EQ(*c->Ingest("video", 0, f0), 20000u);
  ASSERT_EQ(*c->Ingest("video", 1, f1), 30000u);
  auto info = c->Describe("video");
  ASSERT_TRUE(info.ok());
  EXPECT_EQ(info->point_count, 50000u);
  EXPECT_EQ(info->frame_count, 2u);
  // Window and slice, against the points we sent.
  auto all = All(*c, "video", Everything());
  EXPECT_EQ(all.size(), 50000u);
  Window w = Everything();
  w.lo[0] = 2;
  w.hi[0] = 4;
  size_t want = 0;
  for (const auto* v : {&f0, &f1}) {
    for (const Point& p : *v) want += p.x >= 2 && p.x <= 4;
  }
  EXPECT_EQ(All(*c, "video", w).size(), want);
  Slice s;
  s.normal = {0, 0, 0, 1};
  s.offset = 1 / kFps;
  s.thickness = 0.01;
  auto slice = All(*c, "video", s);
  EXPECT_EQ(slice.size(), 30000u);
  // Progressive, coarse first.
  QueryOptions po;
  po.progressive = true;
  po.batch_points = 4096;
  auto q = c->Query("video", FrameWindow(1), po);
  ASSERT_TRUE(q.ok());
  Batch b;
  int last = 99;
  size_t n = 0;
  for (;;) {
    auto more = (*q)->Next(&b);
    ASSERT_TRUE(more.ok());
    if (!*more) break;
    EXPECT_LE(b.level, last);
    last = b.level;
    n += b.points.size();
  }
  EXPECT_EQ(n, 30000u);
  // Edit and revert.
  Transaction t;
  Selection sel;
  sel.region = w;
  t.DeleteSelection(sel);
  auto commit = c->Commit("video", t);
  ASSERT_TRUE(commit.ok()) << commit.status().ToString();
  EXPECT_EQ(commit->removed, want);
  EXPECT_EQ(All(*c, "video", Everything()).size(), 50000u - want);
  auto undo = c->Revert("video", commit->lsn);
  ASSERT_TRUE(undo.ok()) << undo.status().ToString();
  EXPECT_EQ(Ids(All(*c, "video", Everything())), Ids(all));
  // Stats.
  auto st = c->Stats("video");
  ASSERT_TRUE(st.ok());
  EXPECT_GE(st->connections_open(), 1u);
  EXPECT_EQ(st->last_lsn(), undo->lsn);
  EXPECT_GT(st->bytes_out(), 50000u * 64);
  bool saw_query = false;
  for (const auto& k : st->requests()) saw_query |= k.kind() == "query" && k.count() >= 4;
  EXPECT_TRUE(saw_query);
  EXPECT_EQ(st->dataset().points(), 50000u);
  // Typed errors.
  auto missing = c->Describe("nope");
  EXPECT_EQ(missing.status().code(), StatusCode::kNotFound);
  EXPECT_NE(missing.status().message().find("nope"), std::string::npos);
  QueryOptions bad;
  bad.lod = 99;
  auto badq = c->Query("video", Everything(), bad);
  ASSERT_TRUE(badq.ok());  // errors arrive on the stream
  EXPECT_EQ((*badq)->Next(&b).status().code(), StatusCode::kInvalidArgument);
  wire::Request render;
  render.mutable_render()->set_dataset("video");
  auto rid = c->Send(&render);
  ASSERT_TRUE(rid.ok());
  auto rr = c->Receive(*rid);
  ASSERT_TRUE(rr.ok());
  // The render service is built in (tests/render/job_test.cc): a render without a
  // camera is a bad parameter.
  EXPECT_EQ(rr->error().code(), wire::INVALID_PARAMETER);
  EXPECT_EQ(rr->error().parameter(), "render.view");
  // Drop.
  ASSERT_TRUE(c->DropDataset("video").ok());
  EXPECT_TRUE(c->ListDatasets()->empty());
  EXPECT_EQ(server_->Stop(SIGTERM), 0);  // graceful: exit 0
}

TEST_F(ServerTest, AFailedIngestChunkLoadsNothingOfTheFrame) {
  auto c = NewDataset("i");
  std::mt19937_64 rng(11);
  std::vector<uint64_t> ids;
  for (int chunk = 0; chunk < 3; ++chunk) {
    wire::Request r;
    auto* ing = r.mutable_ingest();
    ing->set_dataset("i");
    ing->set_frame(4);
    auto pts = RandomPoints(rng, 10, 4);
    wire::EncodeColumns(pts, ing->mutable_points());
    if (chunk == 1) ing->mutable_points()->set_count(11);  // columns too short: refused
    ing->set_last(chunk == 2);
    ids.push_back(*c->Send(&r));
  }
  EXPECT_TRUE(c->Receive(ids[0])->has_ack());
  EXPECT_EQ(c->Receive(ids[1])->error().code(), wire::INVALID_PARAMETER);
  EXPECT_TRUE(c->Receive(ids[2])->has_error());
  EXPECT_EQ(c->Describe("i")->point_count, 0u);
  // The next frame starts clean.
  EXPECT_EQ(*c->Ingest("i", 4, RandomPoints(rng, 10, 4)), 10u);
}

TEST_F(ServerTest, DracoBatches) {
  auto c = NewDataset("d");
  std::mt19937_64 rng(2);
  auto pts = RandomPoints(rng, 5000, 0);
  ASSERT_TRUE(c->Ingest("d", 0, pts).ok());
  auto o = Opts(server_->port());
  o.draco = true;
  auto dc = Connection::Connect(o);
  ASSERT_TRUE(dc.ok());
  auto exact = All(*c, "d", Everything());
  auto coded = All(**dc, "d", Everything());
  ASSERT_EQ(coded.size(), exact.size());
  std::map<uint64_t, Point> by_id;
  for (const Point& p : exact) by_id[p.id] = p;
  for (const Point& p : coded) {
    ASSERT_TRUE(by_id.count(p.id));
    const Point& e = by_id[p.id];
    EXPECT_NEAR(p.x, e.x, 10.0 / (1 << 15));  // 16-bit quantisation over a 10 m box
    EXPECT_EQ(p.r, e.r);
    EXPECT_EQ(p.frame, e.frame);
  }
}

TEST_F(ServerTest, Hvdb7Batches) {
  auto c = NewDataset("h");
  std::mt19937_64 rng(7);
  auto pts = RandomPoints(rng, 20000, 0);
  ASSERT_TRUE(c->Ingest("h", 0, pts).ok());
  auto o = Opts(server_->port());
  o.hvdb7 = true;
  o.hvdb7_position_bits = 20;
  auto hc = Connection::Connect(o);
  ASSERT_TRUE(hc.ok());
  auto exact = All(*c, "h", Everything());
  auto coded = All(**hc, "h", Everything());
  ASSERT_EQ(coded.size(), exact.size());
  std::map<uint64_t, Point> by_id;
  for (const Point& p : exact) by_id[p.id] = p;
  for (const Point& p : coded) {
    ASSERT_TRUE(by_id.count(p.id));
    const Point& e = by_id[p.id];
    EXPECT_NEAR(p.x, e.x, 10.0 / (1 << 20));  // 20 bits over at most a 10 m batch
    EXPECT_EQ(p.r, e.r);
    EXPECT_EQ(p.g, e.g);
    EXPECT_EQ(p.frame, e.frame);
    EXPECT_EQ(p.label, e.label);
    EXPECT_EQ(p.camera, e.camera);
  }
  // Out-of-range codec parameters are refused up front, naming the field.
  wire::Request r;
  auto* q = r.mutable_query();
  q->set_dataset("h");
  wire::ToWire(Region(Everything()), q->mutable_region());
  q->set_encoding(wire::HVDB7);
  q->mutable_codec()->set_position_bits(31);
  auto id = c->Send(&r);
  ASSERT_TRUE(id.ok());
  auto resp = c->Receive(*id);
  ASSERT_TRUE(resp.ok());
  EXPECT_EQ(resp->error().code(), wire::INVALID_PARAMETER);
  EXPECT_NE(resp->error().message().find("position_bits"), std::string::npos);
  // Only the attributes asked for (what the web page draws), and an unknown name is refused.
  q->mutable_codec()->set_position_bits(0);
  q->mutable_codec()->set_attributes("position,color,label");
  id = c->Send(&r);
  ASSERT_TRUE(id.ok());
  size_t got = 0;
  for (;;) {
    auto part = c->Receive(*id);
    ASSERT_TRUE(part.ok()) << part.status().ToString();
    if (!part->has_batch()) {
      ASSERT_TRUE(part->has_done()) << part->DebugString();
      break;
    }
    codec::StreamInfo info;
    ASSERT_TRUE(codec::ReadInfo(part->batch().hvdb7(), &info).ok());
    EXPECT_EQ(info.attributes, codec::kPosition | codec::kColor | codec::kLabel);
    std::vector<Point> decoded;
    ASSERT_TRUE(wire::DecodeHvdb7(part->batch().hvdb7(), &decoded).ok());
    for (const Point& p : decoded) {
      EXPECT_EQ(p.id, 0u);  // not coded
      ++got;
    }
  }
  EXPECT_EQ(got, exact.size());
  q->mutable_codec()->set_attributes("position,colr");
  id = c->Send(&r);
  ASSERT_TRUE(id.ok());
  resp = c->Receive(*id);
  ASSERT_TRUE(resp.ok());
  EXPECT_EQ(resp->error().code(), wire::INVALID_PARAMETER);
  EXPECT_NE(resp->error().message().find("query.codec.attributes"), std::string::npos)
      << resp->error().message();
  EXPECT_NE(resp->error().message().find("colr"), std::string::npos);
}

TEST_F(ServerTest, PipelinedRequestsAnswerById) {
  auto c = NewDataset("p");
  std::mt19937_64 rng(3);
  ASSERT_TRUE(c->Ingest("p", 0, RandomPoints(rng, 1000, 0)).ok());
  std::vector<uint64_t> ids;
  for (int i = 0; i < 10; ++i) {
    wire::Request r;
    if (i % 2) {
      r.mutable_describe()->set_dataset("p");
    } else {
      r.mutable_ping()->set_payload(std::to_string(i));
    }
    ids.push_back(*c->Send(&r));
  }
  // Collect in reverse order: each answer is matched by id.
  for (int i = 9; i >= 0; --i) {
    auto r = c->Receive(ids[static_cast<size_t>(i)]);
    ASSERT_TRUE(r.ok());
    if (i % 2) {
      EXPECT_EQ(r->info().point_count(), 1000u);
    } else {
      EXPECT_EQ(r->pong().payload(), std::to_string(i));
    }
  }
}

TEST_F(ServerTest, CancelMidStream) {
  auto c = NewDataset("c");
  std::mt19937_64 rng(4);
  // 38 MB of records: more than the flow control's queue and both sockets' kernel buffers
  // (autotuned up to several MiB each), so the query cannot end before the cancel arrives.
  for (uint32_t f = 0; f < 4; ++f) ASSERT_TRUE(c->Ingest("c", f, RandomPoints(rng, 150000, f)).ok());
  QueryOptions o;
  o.batch_points = 1000;
  auto q = c->Query("c", Everything(), o);
  ASSERT_TRUE(q.ok());
  Batch b;
  ASSERT_TRUE(*(*q)->Next(&b));
  ASSERT_TRUE((*q)->Cancel().ok());
  size_t after = 0;
  Status end;
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
  EXPECT_LT(after, 600000u - 1000);  // stopped well before the end
  EXPECT_TRUE(c->Ping().ok());      // the connection is still usable
}

TEST_F(ServerTest, ThirtyTwoConcurrentClientsAgainstAModel) {
  {
    auto c = NewDataset("m");
    std::mt19937_64 rng(5);
    for (uint32_t f = 0; f < 32; ++f) ASSERT_TRUE(c->Ingest("m", f, RandomPoints(rng, 2000, f)).ok());
  }
  std::atomic<int> failures{0};
  std::vector<std::thread> threads;
  for (uint32_t t = 0; t < 32; ++t) {
    threads.emplace_back([&, t] {
      auto c = Connect(server_->port());
      if (!c) {
        ++failures;
        return;
      }
      // Each client owns frame t: its model is exact.
      std::map<uint64_t, Point> model;
      for (const Point& p : All(*c, "m", FrameWindow(t))) model[p.id] = p;
      if (model.size() != 2000) ++failures;
      std::mt19937_64 rng(100 + t);
      for (int round = 0; round < 6; ++round) {
        Transaction txn;
        auto pts = RandomPoints(rng, 50, t);
        txn.Insert(pts);
        Window w = FrameWindow(t);
        w.lo[1] = 0;
        w.hi[1] = 1;  // delete a y-slab
        Selection sel;
        sel.region = w;
        txn.DeleteSelection(sel);
        auto r = c->Commit("m", txn);
        if (!r.ok()) {
          ++failures;
          continue;
        }
        for (size_t i = 0; i < pts.size(); ++i) {
          pts[i].id = r->assigned_ids[i];
          model[pts[i].id] = pts[i];
        }
        std::erase_if(model, [](const auto& e) { return e.second.y >= 0 && e.second.y <= 1; });
        // A window and a slice of this frame agree with the model.
        std::set<uint64_t> want;
        for (const auto& [id, p] : model) want.insert(id);
        if (Ids(All(*c, "m", FrameWindow(t))) != want) ++failures;
        Slice s;
        s.normal = {0, 0, 0, 1};
        s.offset = t / kFps;
        s.thickness = 0.01;
        if (All(*c, "m", s).size() != model.size()) ++failures;
      }
    });
  }
  for (auto& th : threads) th.join();
  EXPECT_EQ(failures.load(), 0);
  auto c = Connect(server_->port());
  auto st = c->Stats("m");
  ASSERT_TRUE(st.ok());
  EXPECT_EQ(st->last_lsn(), 32u + 32u * 6);  // the 32 bulk loads, then 6 commits per client
  EXPECT_GE(st->connections_total(), 33u);
}

// A raw connection for malformed input.
class RawSocket {
 public:
  explicit RawSocket(uint16_t port) {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(port);
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    connected_ = ::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof(a)) == 0;
    timeval tv{5, 0};
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
  }
  ~RawSocket() { ::close(fd_); }
  bool connected() const { return connected_; }
  void Write(const std::string& s) { (void)!::send(fd_, s.data(), s.size(), MSG_NOSIGNAL); }
  void SetReceiveBuffer(int bytes) { ::setsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &bytes, sizeof(bytes)); }
  // Reads frames until the server closes (or 5 s pass); returns the error frames seen.
  std::vector<wire::Response> ReadUntilClosed() {
    std::string buf;
    char tmp[65536];
    for (;;) {
      ssize_t n = ::recv(fd_, tmp, sizeof(tmp), 0);
      if (n <= 0) break;
      buf.append(tmp, static_cast<size_t>(n));
    }
    closed_ = true;
    std::vector<wire::Response> out;
    for (const std::string& payload : testing::FramePayloads(buf)) {
      wire::Response r;
      if (r.ParseFromString(payload)) out.push_back(r);
    }
    return out;
  }
  int fd() const { return fd_; }

 private:
  int fd_;
  bool connected_ = false;
  bool closed_ = false;
};

std::string HelloFrame(uint32_t version = wire::kProtocolVersion) {
  wire::Hello h;
  h.set_protocol_version(version);
  return wire::Frame(h);
}

std::string RawFrame(const std::string& payload) {
  std::string s(4, '\0');
  EncodeLE(reinterpret_cast<uint8_t*>(s.data()), static_cast<uint32_t>(payload.size()));
  return s + payload;
}

TEST_F(ServerTest, MalformedInputGetsErrorsAndOthersKeepWorking) {
  auto good = NewDataset("g");
  std::mt19937_64 rng(6);
  ASSERT_TRUE(good->Ingest("g", 0, RandomPoints(rng, 100, 0)).ok());
  std::vector<std::pair<std::string, std::string>> corpus;
  std::string junk(300, '\0');
  for (char& ch : junk) ch = static_cast<char>(rng());
  corpus.push_back({"random bytes", junk});
  corpus.push_back({"huge length", std::string("\xff\xff\xff\x7f", 4) + "abc"});
  corpus.push_back({"lying length then close", std::string("\x00\x10\x00\x00", 4) + "short"});
  corpus.push_back({"wrong version", HelloFrame(99)});
  corpus.push_back({"hello not protobuf", RawFrame("\xff\xff\xff\xff\xff")});
  wire::Request nan_slice;
  nan_slice.set_id(7);
  auto* q = nan_slice.mutable_query();
  q->set_dataset("g");
  for (double v : {0.0, 0.0, std::nan(""), 1.0}) q->mutable_region()->mutable_slice()->add_normal(v);
  corpus.push_back({"NaN slice", HelloFrame() + wire::Frame(nan_slice)});
  wire::Request bad_enum;
  bad_enum.set_id(8);
  bad_enum.mutable_query()->set_dataset("g");
  bad_enum.mutable_query()->mutable_region()->mutable_window();
  // Encoding 77 does not exist; proto3 keeps unknown enum values, the server must refuse them.
  bad_enum.mutable_query()->set_encoding(static_cast<wire::PointEncoding>(77));
  corpus.push_back({"invalid enum", HelloFrame() + wire::Frame(bad_enum)});
  corpus.push_back({"request not protobuf", HelloFrame() + RawFrame("\x0a\xff\xff\xff\xff\xff\xff")});
  wire::Request empty;
  empty.set_id(9);
  corpus.push_back({"empty request", HelloFrame() + wire::Frame(empty)});
  wire::Request cols;
  cols.set_id(10);
  cols.mutable_ingest()->set_dataset("g");
  cols.mutable_ingest()->mutable_points()->set_count(1000);  // but no column bytes
  cols.mutable_ingest()->set_last(true);
  corpus.push_back({"lying point count", HelloFrame() + wire::Frame(cols)});
  std::string trunc = HelloFrame() + wire::Frame(nan_slice);
  corpus.push_back({"truncated frame", trunc.substr(0, trunc.size() - 3)});

  for (const auto& [name, bytes] : corpus) {
    SCOPED_TRACE(name);
    RawSocket s(server_->port());
    ASSERT_TRUE(s.connected());
    s.Write(bytes);
    ::shutdown(s.fd(), SHUT_WR);  // no more input: the server must answer or close, not hang
    auto responses = s.ReadUntilClosed();
    if (name != "truncated frame" && name != "lying length then close") {
      bool saw_error = false;
      for (const auto& r : responses) saw_error |= r.has_error();
      EXPECT_TRUE(saw_error) << "no error frame";
    }
    // Everyone else is unaffected.
    ASSERT_TRUE(good->Ping().ok());
    EXPECT_EQ(good->Describe("g")->point_count, 100u);
  }
  EXPECT_TRUE(server_->running());
}

TEST_F(ServerTest, SlowReaderDoesNotGrowServerMemory) {
  auto c = NewDataset("s");
  std::mt19937_64 rng(7);
  for (uint32_t f = 0; f < 8; ++f) ASSERT_TRUE(c->Ingest("s", f, RandomPoints(rng, 100000, f)).ok());
  long before = server_->RssKib();
  // 800k points (51 MB) requested by a client that reads nothing.
  RawSocket slow(server_->port());
  slow.SetReceiveBuffer(4096);
  wire::Request q;
  q.set_id(1);
  q.mutable_query()->set_dataset("s");
  auto* w = q.mutable_query()->mutable_region()->mutable_window();
  for (int i = 0; i < 4; ++i) {
    w->add_lo(-1e9);
    w->add_hi(1e9);
  }
  slow.Write(HelloFrame() + wire::Frame(q));
  std::this_thread::sleep_for(std::chrono::milliseconds(1500));
  long during = server_->RssKib();
  // Others are served meanwhile.
  EXPECT_TRUE(c->Ping().ok());
  EXPECT_EQ(All(*c, "s", FrameWindow(3)).size(), 100000u);
  // Bounded: far less than the 51 MB result (flow control keeps ~4 MiB queued).
  EXPECT_LT(during - before, 24 * 1024) << "before " << before << " KiB, during " << during;
}

TEST_F(ServerTest, AcknowledgedCommitsSurviveSigkill) {
  {
    auto c = NewDataset("k");
    std::mt19937_64 rng(8);
    ASSERT_TRUE(c->Ingest("k", 0, RandomPoints(rng, 100, 0)).ok());
  }
  std::atomic<bool> stop{false};
  std::vector<std::pair<uint64_t, std::vector<uint64_t>>> acked;  // lsn, ids
  std::mutex mu;
  std::thread writer([&] {
    auto c = Connect(server_->port());
    std::mt19937_64 rng(9);
    while (!stop) {
      Transaction t;
      t.Insert(RandomPoints(rng, 20, 1));
      auto r = c->Commit("k", t);
      if (!r.ok()) break;
      std::lock_guard<std::mutex> l(mu);
      acked.push_back({r->lsn, r->assigned_ids});
    }
  });
  std::this_thread::sleep_for(std::chrono::milliseconds(400));
  server_->Stop(SIGKILL);
  stop = true;
  writer.join();
  ASSERT_FALSE(acked.empty());
  ServerProcess again(data_);
  ASSERT_TRUE(again.running());
  auto c = Connect(again.port());
  auto ids = Ids(All(*c, "k", FrameWindow(1)));
  for (const auto& [lsn, assigned] : acked) {
    for (uint64_t id : assigned) ASSERT_TRUE(ids.count(id)) << "lost acknowledged commit " << lsn;
  }
  // At most one more (durable, unacknowledged) commit, and never part of one.
  EXPECT_EQ(ids.size() % 20, 0u);
  EXPECT_LE(ids.size(), (acked.size() + 1) * 20);
}

TEST_F(ServerTest, ClientReconnectsWithBackoff) {
  auto c = NewDataset("r");
  c.reset();
  const uint16_t port = server_->port();
  client::Options o = Opts(port);
  o.max_attempts = 20;
  o.backoff = std::chrono::milliseconds(50);
  client::Client cl(o);
  auto describe = [](client::Connection& conn) { return conn.Describe("r"); };
  ASSERT_TRUE(cl.Run<DatasetInfo>(true, describe).ok());
  // The server dies and comes back on the same port a little later.
  server_->Stop(SIGKILL);
  std::thread restart([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    server_ = std::make_unique<ServerProcess>(data_, std::vector<std::string>{},
                                              "127.0.0.1:" + std::to_string(port));
  });
  auto r = cl.Run<DatasetInfo>(true, describe);
  restart.join();
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->name, "r");
}

TEST(ServerLimitsTest, IdleConnectionsAreClosed) {
  TempDir dir;
  ServerProcess server(dir.path() + "/data", {"--idle-timeout", "1"});
  ASSERT_TRUE(server.running());
  RawSocket s(server.port());
  s.Write(HelloFrame());
  auto start = std::chrono::steady_clock::now();
  s.ReadUntilClosed();  // returns when the server closes the connection
  double waited = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_GE(waited, 0.9);
  EXPECT_LT(waited, 4.5);
  // A sender that never finishes its handshake frame is cut off too (slow-loris).
  RawSocket loris(server.port());
  loris.Write(std::string("\x40\x00\x00\x00\x08", 5));
  start = std::chrono::steady_clock::now();
  loris.ReadUntilClosed();
  waited = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_LT(waited, 4.5);
  auto c = Connect(server.port());
  ASSERT_TRUE(c);
  EXPECT_TRUE(c->Ping().ok());
}

TEST_F(ServerTest, EditingOperatorsThroughTheServer) {
  auto c = NewDataset("e");
  auto scene = testing::MovingSphereScene(2, 0.02);
  std::set<uint64_t> sphere;
  for (uint32_t f = 0; f < 2; ++f) {
    std::vector<Point> pts;
    for (const auto& sp : scene) {
      if (sp.p.frame == f) pts.push_back(sp.p);
    }
    ASSERT_TRUE(c->Ingest("e", f, pts).ok());
  }
  for (const Point& p : All(*c, "e", Everything())) {
    if (p.z > 0.001) sphere.insert(p.id);
  }
  auto select = [&](const Window& w, uint32_t bit) {
    wire::SelectRequest q;
    q.set_dataset("e");
    wire::ToWire(Region(w), q.mutable_region());
    q.set_bit(bit);
    return c->Select(q);
  };
  Window top = Everything();
  top.lo = {0.25, 0.45, 0.28, 0};
  top.hi = {0.35, 0.55, 1, 0};
  Window floor = Everything();
  floor.lo = {0.7, 0.0, -1, 0};
  floor.hi = {1.0, 0.3, 0.001, 0};
  ASSERT_TRUE(select(top, 1).ok());
  auto fl = select(floor, 2);
  ASSERT_TRUE(fl.ok());
  EXPECT_GT(fl->selected(), 10u);
  wire::GraphCutRequest gc;
  gc.set_dataset("e");
  wire::ToWire(Region(Everything()), gc.mutable_roi());
  gc.set_foreground_bit(1);
  gc.set_background_bit(2);
  gc.set_out_bit(0);
  gc.set_intra_radius(0.05);
  gc.set_inter_radius(0.08);
  auto cut = c->GraphCut(gc);
  ASSERT_TRUE(cut.ok()) << cut.status().ToString();
  EXPECT_GT(cut->energy(), 0);
  EXPECT_GT(cut->intra_edges(), 0u);
  QueryOptions sel;
  sel.label_mask = 1;
  auto chosen = Ids(All(*c, "e", Everything(), sel));
  size_t tp = 0;
  for (uint64_t id : chosen) tp += sphere.count(id);
  EXPECT_GE(double(tp) / chosen.size(), 0.95);
  EXPECT_GE(double(tp) / sphere.size(), 0.95);
  EXPECT_FALSE(cut->recut());
  // One more stroke (the floor in frame 1), cut again: the server reuses its graph and flow.
  Window floor1 = floor;
  floor1.lo[3] = floor1.hi[3] = 1 / kFps;
  ASSERT_TRUE(select(floor1, 2).ok());
  auto again = c->GraphCut(gc);
  ASSERT_TRUE(again.ok()) << again.status().ToString();
  EXPECT_TRUE(again->recut());
  EXPECT_EQ(again->neighbours_ms(), 0);
  chosen = Ids(All(*c, "e", Everything(), sel));
  // Cut to a clipboard, paste one frame later and 1 m away, undo the cut.
  wire::CopyRequest cp;
  cp.set_dataset("e");
  cp.set_bit(0);
  cp.set_clipboard("ball");
  cp.set_cut(true);
  auto copied = c->Copy(cp);
  ASSERT_TRUE(copied.ok()) << copied.status().ToString();
  EXPECT_EQ(copied->points(), chosen.size());
  EXPECT_TRUE(All(*c, "e", Everything(), sel).empty());
  wire::PasteRequest ps;
  ps.set_dataset("e");
  ps.set_clipboard("ball");
  for (double v : {1.0, 0.0, 0.0, 1 / kFps}) ps.add_offset(v);
  auto pasted = c->Paste(ps);
  ASSERT_TRUE(pasted.ok()) << pasted.status().ToString();
  EXPECT_EQ(pasted->inserted, chosen.size());
  ASSERT_TRUE(c->Revert("e", copied->lsn()).ok());
  // The cut points are back; the pasted copies (still selected, like a fresh paste) stay.
  std::set<uint64_t> both = chosen;
  both.insert(pasted->assigned_ids.begin(), pasted->assigned_ids.end());
  EXPECT_EQ(Ids(All(*c, "e", Everything(), sel)), both);
  // Composite a small object into frames 0..1.
  wire::CompositeRequest comp;
  comp.set_dataset("e");
  std::mt19937_64 rng(12);
  auto object = RandomPoints(rng, 10, 0, 0.1f);
  wire::EncodeColumns(object, comp.mutable_object());
  comp.set_first_frame(0);
  comp.set_frame_count(2);
  auto composed = c->Composite(comp);
  ASSERT_TRUE(composed.ok());
  EXPECT_EQ(composed->inserted, 20u);
  // Typed errors for bad parameters.
  wire::SelectRequest bad;
  bad.set_dataset("e");
  wire::ToWire(Region(Everything()), bad.mutable_region());
  bad.set_bit(40);
  EXPECT_EQ(c->Select(bad).status().code(), StatusCode::kInvalidArgument);
  ps.set_clipboard("missing");
  EXPECT_EQ(c->Paste(ps).status().code(), StatusCode::kNotFound);
}

TEST(ServerAuthTest, TokensAndRoles) {
  TempDir dir;
  std::string tokens = dir.path() + "/tokens";
  {
    std::ofstream(tokens) << "# test tokens\nreadonly-0123456789abcdef ro\nreadwrite-0123456789abcdef rw\n";
  }
  ServerProcess server(dir.path() + "/data", {"--token-file", tokens});
  ASSERT_TRUE(server.running());
  auto none = Connection::Connect(Opts(server.port()));
  ASSERT_FALSE(none.ok());
  EXPECT_EQ(none.status().code(), StatusCode::kPermissionDenied);
  auto rw = Connect(server.port(), "readwrite-0123456789abcdef");
  ASSERT_TRUE(rw);
  DatasetInfo info;
  info.name = "a";
  ASSERT_TRUE(rw->CreateDataset(info).ok());
  auto ro = Connect(server.port(), "readonly-0123456789abcdef");
  ASSERT_TRUE(ro);
  EXPECT_TRUE(ro->Describe("a").ok());
  Transaction t;
  std::mt19937_64 rng(1);
  t.Insert(RandomPoints(rng, 1, 0));
  EXPECT_EQ(ro->Commit("a", t).status().code(), StatusCode::kPermissionDenied);
  EXPECT_EQ(ro->DropDataset("a").code(), StatusCode::kPermissionDenied);
}

TEST(ServerConfigTest, NonLoopbackNeedsTokens) {
  TempDir dir;
  std::string cmd = std::string(HVDB_SERVER_PATH) + " --data " + dir.path() +
                    " --listen 0.0.0.0:0 > /dev/null 2>&1";
  int rc = std::system(cmd.c_str());
  EXPECT_NE(WEXITSTATUS(rc), 0);
}

}  // namespace
}  // namespace hvdb
