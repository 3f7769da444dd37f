// The clients of hostile-soak (declared in soak_clients.h): raw non-blocking loopback sockets,
// hand-built frames (well-formed and broken), the six hostile kinds, and the normal clients that
// time whole-frame window queries through the client library.
#include "soak_clients.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <memory>
#include <random>
#include <string_view>
#include <thread>
#include <vector>

#include <utility>  // before Asio: Boost 1.74's awaitable.hpp needs std::exchange

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/websocket.hpp>

#include "protocol/wire.h"

namespace hvdb::soak {

std::atomic<bool> g_stop_hostile{false};
FdRegistry g_blocking_fds;

namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace websocket = beast::websocket;
using asio::ip::tcp;
using nlohmann::json;
using namespace std::chrono_literals;

constexpr int kRcvBuf = 4096;  // hostile sockets: a small window fills at once

double Ms(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

// ---- Raw sockets ----

// A non-blocking loopback connection; waits up to timeout_ms for it (< 0: does not wait).
int Dial(uint16_t port, int rcvbuf, int timeout_ms) {
  int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd < 0) return -1;
  if (rcvbuf > 0) ::setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof rcvbuf);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(port);
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  int r = ::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
  if (r != 0 && errno != EINPROGRESS) {
    ::close(fd);
    return -1;
  }
  if (r != 0 && timeout_ms >= 0) {
    pollfd p{fd, POLLOUT, 0};
    int err = 0;
    socklen_t len = sizeof err;
    if (::poll(&p, 1, timeout_ms) != 1 ||
        ::getsockopt(fd, SOL_SOCKET, SO_ERROR, &err, &len) != 0 || err != 0) {
      ::close(fd);
      return -1;
    }
  }
  return fd;
}

// Bytes waiting to go out on a non-blocking socket.
struct Out {
  int fd = -1;
  std::string buf;
  size_t off = 0;
  bool pending() const { return off < buf.size(); }
  // Sends what the socket takes now; false when the connection is gone.
  bool Pump() {
    while (off < buf.size()) {
      ssize_t n = ::send(fd, buf.data() + off, buf.size() - off, MSG_NOSIGNAL);
      if (n > 0) {
        off += static_cast<size_t>(n);
      } else if (n < 0 && errno == EINTR) {
        continue;
      } else {
        return n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK);
      }
    }
    buf.clear();
    off = 0;
    return true;
  }
  void Close() {
    if (fd >= 0) ::close(fd);
    fd = -1;
    buf.clear();
    off = 0;
  }
};

// Waits (at most timeout_ms) until one of the pending outputs can take more.
void WaitWritable(const std::vector<Out*>& outs, int timeout_ms) {
  std::vector<pollfd> p;
  for (Out* o : outs) {
    if (o->fd >= 0 && o->pending()) p.push_back({o->fd, POLLOUT, 0});
  }
  if (p.empty()) {
    std::this_thread::sleep_for(std::chrono::milliseconds(timeout_ms));
  } else {
    ::poll(p.data(), p.size(), timeout_ms);
  }
}

// ---- Frames ----

std::string HelloFrame(uint32_t version = wire::kProtocolVersion) {
  wire::Hello h;
  h.set_protocol_version(version);
  h.set_client_name("hostile-soak");
  return wire::Frame(h);
}

// A query for everything: the most the server could be made to hold for one request.
std::string QueryFrame(uint64_t id, wire::PointEncoding enc, int dims = 4) {
  wire::Request r;
  r.set_id(id);
  wire::Query* q = r.mutable_query();
  q->set_dataset(kDataset);
  q->set_encoding(enc);
  wire::Window* w = q->mutable_region()->mutable_window();
  for (int i = 0; i < dims; ++i) {
    w->add_lo(-1e30);
    w->add_hi(1e30);
  }
  return wire::Frame(r);
}

std::string PingFrame(uint64_t id, std::string_view payload) {
  wire::Request r;
  r.set_id(id);
  r.mutable_ping()->set_payload(std::string(payload));
  return wire::Frame(r);
}

std::string Le32(uint32_t v) {
  std::string s(4, '\0');
  for (int i = 0; i < 4; ++i) s[i] = static_cast<char>((v >> (8 * i)) & 0xff);
  return s;
}

std::string RandomBytes(std::mt19937_64& rng, size_t n) {
  std::string s(n, '\0');
  for (auto& c : s) c = static_cast<char>(rng());
  return s;
}

// The kinds of broken input a confused or hostile client sends (docs/PROTOCOL.md, "Framing").
std::string MalformedBytes(int kind, std::mt19937_64& rng) {
  switch (kind) {
    case 0: return RandomBytes(rng, 4096);                                 // noise, no Hello
    case 1: return HelloFrame() + Le32(0x7fffffffu) + RandomBytes(rng, 16);  // length over max
    case 2: return HelloFrame() + Le32(7 | wire::kAttachmentFlag) + Le32(64) +
                   RandomBytes(rng, 71);                                  // client attachment
    case 3: return HelloFrame() + Le32(64) + RandomBytes(rng, 64);        // not a Request
    case 4: return HelloFrame() + Le32(1u << 20) + RandomBytes(rng, 100);  // truncated frame
    case 5: return HelloFrame(1);                                          // old version
    default:  // a bad window (the connection stays open), then a header of all ones
      return HelloFrame() + QueryFrame(1, wire::RECORDS, 3) + Le32(0xffffffffu);
  }
}

// ---- Hostile clients ----

// Hello and n whole-dataset queries (COLUMNS and RECORDS in turn) on a new connection with a
// small receive window; -1 when the server could not be reached or did not take them all.
int OpenQuerying(uint16_t port, int n) {
  Out o;
  o.fd = Dial(port, kRcvBuf, 2000);
  if (o.fd < 0) return -1;
  o.buf = HelloFrame();
  for (int q = 0; q < n; ++q) {
    o.buf += QueryFrame(static_cast<uint64_t>(q + 1), q % 2 ? wire::RECORDS : wire::COLUMNS);
  }
  if (o.Pump() && !o.pending()) return o.fd;
  o.Close();
  return -1;
}

}  // namespace

// (a) kQueriesPerNonReader whole-dataset queries each, and never a byte read.
void NonReaders(const Setup& s, Counters& c) {
  std::vector<int> fds;
  for (int i = 0; i < s.non_readers && !g_stop_hostile; ++i) {
    if (int fd = OpenQuerying(s.port, kQueriesPerNonReader); fd >= 0) {
      fds.push_back(fd);
      ++c["non_reader_conns"];
    }
  }
  while (!g_stop_hostile) std::this_thread::sleep_for(100ms);
  for (int fd : fds) ::close(fd);
}

// (b) The same over the WebSocket: JSON Hello, its reply, then queries, never read again.
void WsNonReaders(const Setup& s, Counters& c) {
  asio::io_context io;
  std::vector<std::unique_ptr<websocket::stream<tcp::socket>>> streams;
  const std::string host = "127.0.0.1:" + std::to_string(s.http_port);
  const std::string hello = R"({"protocol_version": 2, "client_name": "hostile-soak"})";
  for (int i = 0; i < s.ws_non_readers && !g_stop_hostile; ++i) {
    auto ws = std::make_unique<websocket::stream<tcp::socket>>(io);
    beast::error_code ec;
    tcp::socket& sock = ws->next_layer();
    sock.open(tcp::v4(), ec);
    if (ec) break;
    sock.set_option(asio::socket_base::receive_buffer_size(kRcvBuf), ec);
    const int fd = sock.native_handle();
    g_blocking_fds.Add(fd);
    sock.connect({asio::ip::address_v4::loopback(), s.http_port}, ec);
    if (!ec) ws->handshake(host, "/ws", ec);
    ws->text(true);
    if (!ec) ws->write(asio::buffer(hello), ec);
    beast::flat_buffer reply;
    if (!ec) ws->read(reply, ec);  // the HelloReply (or an error, then a close)
    for (int q = 0; q < kQueriesPerNonReader && !ec; ++q) {
      std::string m = R"({"id":)" + std::to_string(q + 1) + R"(,"query":{"dataset":")" + kDataset +
                      R"(","region":{"window":{"lo":[-1e30,-1e30,-1e30,-1e30],)"
                      R"("hi":[1e30,1e30,1e30,1e30]}},"lod":0,"encoding":"COLUMNS"}})";
      ws->write(asio::buffer(m), ec);
    }
    if (ec) {
      ++c["ws_failed"];
      g_blocking_fds.Remove(fd);
      sock.close(ec);
      continue;
    }
    ++c["ws_conns"];
    streams.push_back(std::move(ws));
  }
  while (!g_stop_hostile) std::this_thread::sleep_for(100ms);
  for (auto& ws : streams) {
    beast::error_code ec;
    g_blocking_fds.Remove(ws->next_layer().native_handle());
    ws->next_layer().close(ec);  // abruptly: a client that vanished
  }
}

// (c) Whole-dataset queries read at 4 KiB every 100 ms; reconnecting when dropped.
void SlowReaders(const Setup& s, Counters& c) {
  std::vector<int> fds(static_cast<size_t>(s.slow_readers), -1);
  std::vector<char> buf(4096);
  int opens = 0;
  while (!g_stop_hostile) {
    for (auto& fd : fds) {
      if (fd >= 0 || opens >= 100 * s.slow_readers) continue;
      ++opens;
      fd = OpenQuerying(s.port, 4);
      if (fd >= 0) ++c["slow_conns"];
    }
    for (auto& fd : fds) {
      if (fd < 0) continue;
      ssize_t n = ::recv(fd, buf.data(), buf.size(), MSG_DONTWAIT);
      if (n > 0) {
        c["slow_bytes_read"] += n;
      } else if (n == 0 || (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)) {
        ++c["slow_closed"];
        ::close(fd);
        fd = -1;
      }
    }
    std::this_thread::sleep_for(100ms);
  }
  for (int fd : fds) {
    if (fd >= 0) ::close(fd);
  }
}

// (d) 40 pings of 1 MiB, then 4 of 8 MiB (over any sane ping limit, under --max-frame-bytes),
// never reading a pong. A connection the server drops is opened again, at most 10 times.
void PingFloods(const Setup& s, Counters& c) {
  constexpr int kSmall = 40, kBig = 4, kRounds = 10;
  const std::string payload(8u << 20, 'p');
  struct Flood {
    Out out;
    int next = 0, rounds = 0;
  };
  std::vector<Flood> floods(static_cast<size_t>(s.ping_floods));
  while (!g_stop_hostile) {
    std::vector<Out*> outs;
    for (auto& f : floods) {
      if (f.out.fd < 0 && f.rounds < kRounds) {
        ++f.rounds;
        f.out.fd = Dial(s.port, kRcvBuf, 2000);
        if (f.out.fd < 0) continue;
        ++c["ping_conns"];
        f.out.buf = HelloFrame();
        f.next = 0;
      }
      if (f.out.fd < 0) continue;
      if (!f.out.pending() && f.next < kSmall + kBig) {
        size_t n = f.next < kSmall ? (1u << 20) : payload.size();
        f.out.buf = PingFrame(static_cast<uint64_t>(f.next + 1),
                              std::string_view(payload).substr(0, n));
        ++f.next;
        ++c["pings_sent"];
      }
      if (!f.out.Pump()) {
        ++c["ping_conns_closed"];
        f.out.Close();
      }
      outs.push_back(&f.out);
    }
    WaitWritable(outs, 50);
  }
  for (auto& f : floods) f.out.Close();
}

// (e) Broken frames of every kind, one connection each, as fast as the server answers.
void Malformed(const Setup& s, int seed, Counters& c) {
  std::mt19937_64 rng(static_cast<uint64_t>(seed));
  std::vector<char> buf(4096);
  for (int k = 0; k < 20000 && !g_stop_hostile; ++k) {
    Out o;
    o.fd = Dial(s.port, 0, 1000);
    if (o.fd < 0) {
      std::this_thread::sleep_for(20ms);
      continue;
    }
    o.buf = MalformedBytes(k % 7, rng);
    auto deadline = Clock::now() + 300ms;
    bool alive = o.Pump();
    while (alive && o.pending() && Clock::now() < deadline) {
      WaitWritable({&o}, 20);
      alive = o.Pump();
    }
    ++c["malformed_sent"];
    // Read what the server says, until it closes (counted) or 300 ms pass.
    while (alive && Clock::now() < deadline) {
      pollfd p{o.fd, POLLIN, 0};
      if (::poll(&p, 1, 20) <= 0) continue;
      ssize_t n = ::recv(o.fd, buf.data(), buf.size(), MSG_DONTWAIT);
      if (n == 0 || (n < 0 && errno != EAGAIN && errno != EINTR)) alive = false;
    }
    if (!alive) ++c["malformed_closed_by_server"];
    o.Close();
    std::this_thread::sleep_for(10ms);
  }
}

// (f) Connect and say nothing; reconnect 100 ms after the server drops one.
void Squatters(const Setup& s, Counters& c) {
  struct Sq {
    int fd = -1;
    Clock::time_point retry;
  };
  std::vector<Sq> sq(static_cast<size_t>(s.squatters));
  std::vector<char> buf(4096);
  while (!g_stop_hostile) {
    auto now = Clock::now();
    for (auto& q : sq) {
      if (q.fd >= 0 || now < q.retry || c["squatter_connects"] >= 200000) continue;
      q.fd = Dial(s.port, 0, -1);
      if (q.fd < 0) {
        q.retry = now + 100ms;
      } else {
        ++c["squatter_connects"];
      }
    }
    std::vector<pollfd> p;
    for (auto& q : sq) {
      if (q.fd >= 0) p.push_back({q.fd, POLLIN | POLLRDHUP, 0});
    }
    c["squatters_open_at_end"] = static_cast<long>(p.size());
    if (::poll(p.data(), p.size(), 100) <= 0) continue;
    for (auto& pf : p) {
      if (!pf.revents) continue;
      bool gone = (pf.revents & (POLLERR | POLLHUP)) != 0;
      for (;;) {  // an OVERLOADED error frame, then the end
        ssize_t n = ::recv(pf.fd, buf.data(), buf.size(), MSG_DONTWAIT);
        if (n > 0) continue;
        if (n == 0 || (errno != EAGAIN && errno != EINTR)) gone = true;
        break;
      }
      if (!gone) continue;
      auto it = std::find_if(sq.begin(), sq.end(), [&](const Sq& x) { return x.fd == pf.fd; });
      ::close(pf.fd);
      it->fd = -1;
      it->retry = Clock::now() + 100ms;
      ++c["squatter_drops"];
    }
  }
  for (auto& q : sq) {
    if (q.fd >= 0) ::close(q.fd);
  }
}

// ---- Normal clients ----

namespace {

struct NormalResult {
  std::vector<double> lat_ms;
  long queries = 0, points = 0, errors = 0, refused = 0;
  double connect_ms = -1;  // from the window's start to the first connection that worked
};

// Whole-frame windows, frame after frame, from `start` to `end`. With connect_early the
// connection is made before `start` (unloaded phase: only queries are timed); else inside the
// window, so that a server refusing new connections shows in the figures.
void Normal(const Setup& s, int idx, bool connect_early, Clock::time_point start,
            Clock::time_point end, NormalResult* out) {
  std::unique_ptr<client::Connection> c;
  auto connect = [&]() {
    auto r = client::Connection::Connect(ClientOptions(s.port));
    if (!r.ok()) {
      ++out->refused;
      return false;
    }
    c = std::move(r).value();
    if (out->connect_ms < 0) out->connect_ms = std::max(0.0, Ms(start, Clock::now()));
    return true;
  };
  if (connect_early) connect();
  std::this_thread::sleep_until(start);
  uint32_t f = static_cast<uint32_t>(idx);
  while (Clock::now() < end) {
    if (!c && !connect()) {
      std::this_thread::sleep_for(100ms);
      continue;
    }
    Window w;
    double t = (f % s.frames) / kFps;
    w.lo = {-1e30, -1e30, -1e30, t};
    w.hi = {1e30, 1e30, 1e30, t};
    auto t0 = Clock::now();
    long n = 0;
    bool ok;
    {
      auto q = c->Query(kDataset, Region(w), {});
      ok = q.ok();
      client::BatchView v;
      while (ok) {
        auto more = (*q)->NextView(&v);
        if (!more.ok()) ok = false;
        if (!ok || !*more) break;
        n += static_cast<long>(v.points.size());
      }
    }
    auto t1 = Clock::now();
    if (!ok) {
      ++out->errors;
      if (c->broken()) c.reset();
      std::this_thread::sleep_for(10ms);  // an OVERLOADED answer: no busy loop on it
      continue;
    }
    ++f;
    out->lat_ms.push_back(Ms(t0, t1));  // one that overran the window still says how long it took
    if (t1 > end) break;  // only whole queries inside the window count towards throughput
    ++out->queries;
    out->points += n;
  }
}

double Percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  size_t i = static_cast<size_t>(p * static_cast<double>(v.size() - 1) + 0.5);
  return v[std::min(i, v.size() - 1)];
}

}  // namespace

client::Options ClientOptions(uint16_t port) {
  client::Options o;
  o.port = port;
  o.prefer_local = false;  // the server listens on TCP only: the path hostile clients share
  o.connect_timeout = 2000ms;
  o.request_timeout = 5000ms;
  o.max_attempts = 1;
  return o;
}

json RunNormals(const Setup& s, int k, double seconds, bool connect_early) {
  std::vector<NormalResult> r(static_cast<size_t>(k));
  auto start = Clock::now() + (connect_early ? 500ms : 0ms);
  auto end = start + std::chrono::milliseconds(static_cast<long>(seconds * 1000));
  std::vector<std::thread> ts;
  for (int i = 0; i < k; ++i) {
    ts.emplace_back(Normal, std::cref(s), i, connect_early, start, end, &r[static_cast<size_t>(i)]);
  }
  for (auto& t : ts) t.join();
  NormalResult all;
  json connect_ms = json::array();
  for (auto& x : r) {
    all.lat_ms.insert(all.lat_ms.end(), x.lat_ms.begin(), x.lat_ms.end());
    all.queries += x.queries;
    all.points += x.points;
    all.errors += x.errors;
    all.refused += x.refused;
    connect_ms.push_back(x.connect_ms);
  }
  return {{"queries", all.queries},
          {"queries_per_s", static_cast<double>(all.queries) / seconds},
          {"points_per_s", static_cast<double>(all.points) / seconds},
          {"p50_ms", Percentile(all.lat_ms, 0.50)},
          {"p99_ms", Percentile(all.lat_ms, 0.99)},
          {"max_ms", Percentile(all.lat_ms, 1.0)},
          {"errors", all.errors},
          {"refused_connects", all.refused},
          {"connect_ms", connect_ms}};
}

}  // namespace hvdb::soak
