// Watch requests against a real hvdb-server (docs/PROTOCOL.md, "Watching"): the same events in
// commit order on binary TCP, the Unix socket (with its shared-memory ring) and the WebSocket;
// a resume from an LSN that loses and repeats nothing; a watcher that stops reading ends with
// LAGGED while the server's buffers stay bounded, and resumes; a drop and a cancel end watches.
#include <gtest/gtest.h>

#include <chrono>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "client/client.h"
#include "tests/server/server_process.h"
#include "tests/server/ws_client.h"
#include "tests/storage/test_util.h"

namespace hvdb {
namespace {

using client::Connection;
using nlohmann::json;
using testing::RandomPoints;
using testing::ServerProcess;
using testing::TempDir;
using testing::Ws;
using Kind = ChangeEvent::Kind;
using std::chrono::milliseconds;

class WatchServerTest : public ::testing::Test {
 protected:
  void Start(std::vector<std::string> extra = {}) {
    sock_ = dir_.path() + "/s.sock";
    extra.insert(extra.end(), {"--listen", "unix:" + sock_, "--http", "127.0.0.1:0"});
    server_ = std::make_unique<ServerProcess>(dir_.path() + "/data", extra);
    ASSERT_TRUE(server_->running());
    writer_ = Tcp();
    DatasetInfo info;
    info.name = "live";
    info.fps = 30;
    ASSERT_TRUE(writer_->CreateDataset(info).ok());
  }
  std::unique_ptr<Connection> Tcp() {
    client::Options o;
    o.port = server_->port();
    o.prefer_local = false;
    auto c = Connection::Connect(o);
    EXPECT_TRUE(c.ok()) << c.status().ToString();
    return c.ok() ? std::move(*c) : nullptr;
  }
  std::unique_ptr<Connection> Unix() {
    client::Options o;
    o.unix_path = sock_;
    auto c = Connection::Connect(o);
    EXPECT_TRUE(c.ok()) << c.status().ToString();
    return c.ok() ? std::move(*c) : nullptr;
  }
  // A mix of changes: transactions, bulk loads (Ingest), a revert. Returns the LSNs.
  std::vector<uint64_t> Changes(int n) {
    std::vector<uint64_t> lsns;
    for (int i = 0; i < n; ++i) {
      const uint32_t frame = static_cast<uint32_t>(i % 7);
      if (i % 5 == 3) {
        auto pts = RandomPoints(rng_, 300, frame);
        EXPECT_TRUE(writer_->Ingest("live", frame, pts).ok());
        lsns.push_back(lsns.empty() ? 1 : lsns.back() + 1);
      } else if (i % 5 == 4) {
        auto r = writer_->Revert("live", lsns[lsns.size() - 2]);  // change i - 2, a commit
        EXPECT_TRUE(r.ok()) << r.status().ToString();
        lsns.push_back(r.ok() ? r->lsn : 0);
      } else {
        Transaction t;
        t.Insert(RandomPoints(rng_, 20, frame));
        auto c = writer_->Commit("live", t);
        EXPECT_TRUE(c.ok()) << c.status().ToString();
        lsns.push_back(c.ok() ? c->lsn : 0);
      }
    }
    return lsns;
  }
  // Reads events until `count` changes (not LIVE) came, or 10 s passed.
  static std::vector<ChangeEvent> Read(client::WatchStream& w, size_t count) {
    std::vector<ChangeEvent> out;
    const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    ChangeEvent ev;
    while (out.size() < count && std::chrono::steady_clock::now() < end) {
      auto got = w.Next(&ev, milliseconds(200));
      EXPECT_TRUE(got.ok()) << got.status().ToString();
      if (!got.ok()) break;
      if (*got && ev.kind != Kind::kLive) out.push_back(ev);
    }
    return out;
  }

  TempDir dir_;
  std::string sock_;
  std::unique_ptr<ServerProcess> server_;
  std::unique_ptr<Connection> writer_;
  std::mt19937_64 rng_{7};
};

// A WebSocket watcher: the events as JSON.
struct WsWatcher {
  Ws ws;
  void Open(uint16_t port, std::optional<uint64_t> from = std::nullopt) {
    ASSERT_EQ(ws.Open(port), 101u);
    ASSERT_TRUE(ws.Hello().contains("protocol_version"));
    json w = {{"dataset", "live"}};
    if (from) w["from_lsn"] = std::to_string(*from);
    ws.Text(json{{"id", "9"}, {"watch", w}}.dump());
  }
  std::vector<json> Read(size_t count) {
    std::vector<json> out;
    while (out.size() < count) {
      json j = ws.ReadJson();
      if (!j.contains("event")) {
        ADD_FAILURE() << "not an event: " << j.dump();
        break;
      }
      if (j["event"]["kind"] != "WATCH_LIVE") out.push_back(j["event"]);
    }
    return out;
  }
};

TEST_F(WatchServerTest, EveryTransportSeesTheSameEventsInCommitOrder) {
  Start();
  auto tcp = Tcp(), unix_conn = Unix();
  ASSERT_TRUE(tcp && unix_conn);
  EXPECT_EQ(unix_conn->transport(), "unix " + sock_ + " + shared memory");
  auto wt = tcp->Watch("live");
  auto wu = unix_conn->Watch("live");
  ASSERT_TRUE(wt.ok() && wu.ok());
  WsWatcher ws;
  ws.Open(server_->http_port());
  ws.Read(0);
  // The WebSocket watch is in place once its LIVE came.
  json live = ws.ws.ReadJson();
  ASSERT_EQ(live["event"]["kind"], "WATCH_LIVE") << live.dump();

  const auto lsns = Changes(25);
  auto et = Read(**wt, lsns.size()), eu = Read(**wu, lsns.size());
  auto ew = ws.Read(lsns.size());
  ASSERT_EQ(et.size(), lsns.size());
  ASSERT_EQ(eu.size(), lsns.size());
  for (size_t i = 0; i < lsns.size(); ++i) {
    SCOPED_TRACE("event " + std::to_string(i));
    EXPECT_EQ(et[i].lsn, lsns[i]);
    EXPECT_EQ(et[i].lsn, i + 1);
    EXPECT_EQ(eu[i].lsn, et[i].lsn);
    EXPECT_EQ(eu[i].kind, et[i].kind);
    EXPECT_EQ(eu[i].frames, et[i].frames);
    EXPECT_EQ(eu[i].points, et[i].points);
    EXPECT_EQ(ew[i]["lsn"], std::to_string(et[i].lsn));
    EXPECT_EQ(ew[i]["frames"], json(et[i].frames));
    EXPECT_EQ(ew[i]["points"], std::to_string(et[i].points));
    const Kind want = i % 5 == 3 ? Kind::kBulk : i % 5 == 4 ? Kind::kRevert : Kind::kCommit;
    EXPECT_EQ(et[i].kind, want);
    EXPECT_EQ(ew[i]["kind"], std::string("WATCH_") + (want == Kind::kBulk     ? "BULK"
                                                      : want == Kind::kRevert ? "REVERT"
                                                                              : "COMMIT"));
  }
  EXPECT_EQ(et[3].points, 300u);
}

TEST_F(WatchServerTest, AResumeFromAnLsnLosesNothingAndRepeatsNothing) {
  Start();
  const auto first = Changes(12);
  auto c = Unix();
  for (uint64_t from : {uint64_t{0}, uint64_t{5}, first.back()}) {
    SCOPED_TRACE("from " + std::to_string(from));
    auto w = c->Watch("live", from);
    ASSERT_TRUE(w.ok()) << w.status().ToString();
    auto replayed = Read(**w, first.back() - from);
    ASSERT_EQ(replayed.size(), first.back() - from);
    for (size_t i = 0; i < replayed.size(); ++i) EXPECT_EQ(replayed[i].lsn, from + 1 + i);
  }
  // A watch resumed while the writer goes on sees every change once.
  auto w = c->Watch("live", 3);
  ASSERT_TRUE(w.ok());
  const auto more = Changes(10);
  auto ev = Read(**w, more.back() - 3);
  ASSERT_EQ(ev.size(), more.back() - 3);
  for (size_t i = 0; i < ev.size(); ++i) ASSERT_EQ(ev[i].lsn, 4 + i);
  // Past the last LSN: a clear error.
  auto past = c->Watch("live", more.back() + 5);
  ASSERT_FALSE(past.ok());
  EXPECT_NE(past.status().message().find("past"), std::string::npos) << past.status().ToString();
  auto unknown = c->Watch("nope");
  ASSERT_FALSE(unknown.ok());
  EXPECT_NE(unknown.status().message().find("no dataset 'nope'"), std::string::npos);
}

TEST_F(WatchServerTest, AWatcherThatStopsReadingLagsWithinABoundAndResumes) {
  Start({"--connection-buffer-kib", "256"});
  auto slow = Unix();
  wire::Request req;
  req.mutable_watch()->set_dataset("live");
  auto id = slow->Send(&req);
  ASSERT_TRUE(id.ok());
  // Events of transactions touching 4,000 frames each (~8 KB): the socket's buffers fill, then
  // the connection's queue reaches its high-water mark.
  std::this_thread::sleep_for(milliseconds(200));
  const int kCommits = 250;
  uint64_t last = 0;
  int64_t max_buffered = 0;
  auto commit = [&] {
    Transaction t;
    std::vector<Point> pts;
    for (uint32_t f = 0; f < 4000; ++f) {
      auto p = RandomPoints(rng_, 1, f);
      pts.push_back(p[0]);
    }
    t.Insert(std::move(pts));
    auto c = writer_->Commit("live", t);
    ASSERT_TRUE(c.ok()) << c.status().ToString();
    last = c->lsn;
  };
  for (int i = 0; i < kCommits; ++i) {
    commit();
    if (i % 20 == 19) {
      auto st = writer_->Stats();
      ASSERT_TRUE(st.ok());
      max_buffered = std::max<int64_t>(max_buffered, static_cast<int64_t>(st->buffered_bytes()));
    }
  }
  // What the server holds for all connections stays near the watcher's high-water mark.
  // (The mark is 256 KiB; a watch may queue up to four times it while a replay bursts.)
  EXPECT_LT(max_buffered, 1536 << 10) << "a watcher that does not read grew the server";
  // Now read: events, then LAGGED naming where to resume.
  uint64_t seen = 0, resume = 0;
  bool lagged = false;
  while (!lagged) {
    auto r = slow->Receive(*id);
    ASSERT_TRUE(r.ok()) << r.status().ToString();
    ASSERT_TRUE(r->has_event()) << r->DebugString();
    const auto& e = r->event();
    if (e.kind() == wire::WATCH_LAGGED) {
      lagged = true;
      resume = e.lsn();
    } else if (e.kind() != wire::WATCH_LIVE) {
      EXPECT_EQ(e.lsn(), seen + 1);
      seen = e.lsn();
    }
  }
  EXPECT_EQ(resume, seen);
  EXPECT_LT(seen, last) << "the watcher never lagged";
  // Resume: the rest, exactly, in one watch: the replay (past four times the mark) is paced by
  // what this client reads, not cut short. (On a loaded machine the watch may lag late in the
  // commits: the backlog is made that large first.)
  while ((last - resume) * 8000 <= 5u * (256u << 10)) commit();
  auto w = slow->Watch("live", resume);
  ASSERT_TRUE(w.ok()) << w.status().ToString();
  uint64_t next = resume + 1;
  ChangeEvent ev;
  while (next <= last) {
    auto got = (*w)->Next(&ev, milliseconds(5000));
    ASSERT_TRUE(got.ok()) << got.status().ToString();
    ASSERT_TRUE(*got) << "no event for 5 s";
    if (ev.kind == Kind::kLive) continue;
    ASSERT_NE(ev.kind, Kind::kLagged) << "a reading client lagged during the replay at " << ev.lsn;
    ASSERT_EQ(ev.lsn, next) << "lost or repeated";
    ++next;
  }
}

// A client that asks for a long replay and does not read holds no worker and no memory: the
// replay stops after a second without progress, and the watch ends with LAGGED.
TEST_F(WatchServerTest, AReplayNobodyReadsEndsWithLagged) {
  Start({"--connection-buffer-kib", "256", "--workers", "2"});
  for (int i = 0; i < 60; ++i) {
    Transaction t;
    std::vector<Point> pts;
    // Events of ~16 KB: the replay (~1 MB) outgrows the socket's buffers and the window.
    for (uint32_t f = 0; f < 8000; ++f) pts.push_back(RandomPoints(rng_, 1, f)[0]);
    t.Insert(std::move(pts));
    ASSERT_TRUE(writer_->Commit("live", t).ok());
  }
  std::vector<std::unique_ptr<Connection>> idle;
  for (int i = 0; i < 4; ++i) {  // more than the workers
    idle.push_back(Unix());
    wire::Request req;
    req.mutable_watch()->set_dataset("live");
    req.mutable_watch()->set_from_lsn(0);
    ASSERT_TRUE(idle.back()->Send(&req).ok());
  }
  // Until the server has ended all four watches (its request statistics count a watch when it
  // ends): reading the log may take a while (sanitizer builds), the stall a second more.
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(120);
  for (;;) {
    auto st = writer_->Stats();
    ASSERT_TRUE(st.ok());
    uint64_t ended = 0;
    for (const auto& l : st->requests()) {
      if (l.kind() == "watch") ended = l.count();
    }
    if (ended >= idle.size()) break;
    ASSERT_LT(std::chrono::steady_clock::now(), until) << ended << " of the watches ended";
    std::this_thread::sleep_for(milliseconds(200));
  }
  // The workers are free: a commit (run on a worker) answers at once.
  const auto t0 = std::chrono::steady_clock::now();
  Transaction t;
  t.Insert(RandomPoints(rng_, 10, 0));
  ASSERT_TRUE(writer_->Commit("live", t).ok());
  EXPECT_LT(std::chrono::steady_clock::now() - t0, milliseconds(1000));
  // Each idle watcher finds, once it reads, a prefix of the log and then LAGGED.
  for (auto& c : idle) {
    uint64_t seen = 0;
    for (;;) {
      auto r = c->Receive(1);
      ASSERT_TRUE(r.ok()) << r.status().ToString();
      ASSERT_TRUE(r->has_event());
      ASSERT_NE(r->event().kind(), wire::WATCH_LIVE) << "the whole replay was sent to a client "
                                                        "that did not read";
      if (r->event().kind() == wire::WATCH_LAGGED) {
        EXPECT_EQ(r->event().lsn(), seen);
        break;
      }
      ASSERT_EQ(r->event().lsn(), seen + 1);
      seen = r->event().lsn();
    }
    EXPECT_LT(seen, 60u);
  }
}

TEST_F(WatchServerTest, ADropAndACancelEndWatches) {
  Start();
  auto c = Tcp(), d = Tcp();
  auto dropped = c->Watch("live");
  auto cancelled = d->Watch("live");
  ASSERT_TRUE(dropped.ok() && cancelled.ok());
  Changes(2);
  ASSERT_EQ(Read(**cancelled, 2).size(), 2u);
  ASSERT_TRUE((*cancelled)->Cancel().ok());
  ChangeEvent ev;
  auto got = (*cancelled)->Next(&ev, milliseconds(5000));
  ASSERT_FALSE(got.ok());
  EXPECT_EQ(got.status().code(), StatusCode::kCancelled) << got.status().ToString();
  EXPECT_TRUE(d->Ping().ok()) << "the connection goes on after a cancelled watch";

  ASSERT_TRUE(writer_->DropDataset("live").ok());
  std::vector<ChangeEvent> all;
  for (int i = 0; i < 50 && !(*dropped)->ended(); ++i) {
    auto r = (*dropped)->Next(&ev, milliseconds(200));
    ASSERT_TRUE(r.ok()) << r.status().ToString();
    if (*r) all.push_back(ev);
  }
  ASSERT_FALSE(all.empty());
  EXPECT_EQ(all.back().kind, Kind::kDropped);
  EXPECT_EQ(all.size(), 4u);  // LIVE, two changes, DROPPED
}

}  // namespace
}  // namespace hvdb
