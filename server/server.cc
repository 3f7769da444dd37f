#include "server/server.h"

#include "storage/job_limits.h"
#include "storage/log.h"
#include "storage/rados_env.h"

#include <malloc.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <ctime>
#include <fstream>
#include <sstream>

#include "server/http.h"
#include "client/client.h"
#include "server/session.h"

namespace hvdb::server {

namespace asio = boost::asio;
using asio::ip::tcp;

static std::atomic<int> g_log_level{static_cast<int>(LogLevel::kInfo)};

void SetLogLevel(LogLevel level) { g_log_level = static_cast<int>(level); }

void Log(LogLevel level, const std::string& msg) {
  if (static_cast<int>(level) > g_log_level) return;
  static const char* kNames[] = {"ERROR", "WARN", "INFO", "DEBUG"};
  char ts[32];
  std::time_t now = std::time(nullptr);
  std::strftime(ts, sizeof(ts), "%Y-%m-%dT%H:%M:%S", std::gmtime(&now));
  std::fprintf(stderr, "%sZ %s %s\n", ts, kNames[static_cast<int>(level)], msg.c_str());
}

Server::Server(Config config, std::unique_ptr<Database> db)
    : config_(std::move(config)),
      db_(std::move(db)),
      io_(static_cast<int>(config_.io_threads)),
      workers_(config_.worker_threads),
      renders_(config_.max_renders),
      service_(db_.get(), config_.data_dir, db_->options().env, &graph_cuts_,
               service::JobConfig{config_.memory_budget, config_.max_job_seconds}),
      acceptor_(io_),
      unix_acceptor_(io_),
      signals_(io_),
      trim_timer_(asio::make_strand(io_)) {
  // The engine's warnings and notes go into the server's log, with its timestamps and levels.
  hvdb::SetLogHandler([](LogSeverity s, const std::string& m) {
    Log(s == LogSeverity::kWarning ? LogLevel::kWarn : LogLevel::kInfo, m);
  });
  // The stats and server_stats requests report this process through the executor.
  service_.SetCounters([this] { return Counters(); });
}

service::ServerCounters Server::Counters() {
  service::ServerCounters c;
  c.connections_open = stats_.connections_open;
  c.connections_total = stats_.connections_total;
  c.bytes_in = stats_.bytes_in;
  c.bytes_out = stats_.bytes_out;
  c.role = role();
  c.leader = db_->Leader();
  c.buffered_bytes = static_cast<uint64_t>(std::max<int64_t>(0, buffered()));
  c.memory_budget_bytes = budget_;
  CacheStats cache = db_->Cache();
  c.cache_capacity_bytes = cache.capacity_bytes;
  const uint64_t lookups = cache.hits + cache.misses;
  c.cache_hit_rate = lookups ? static_cast<double>(cache.hits) / lookups : 0;
  for (const auto& sum : stats_.Summaries()) {
    c.requests.push_back({sum.kind, sum.count, sum.p50_ms, sum.p95_ms, sum.p99_ms});
  }
  return c;
}

Server::~Server() {
  Stop();
  {
    std::lock_guard<std::mutex> l(follow_mu_);
    follow_stop_ = true;
  }
  follow_cv_.notify_all();
  if (follower_.joinable()) follower_.join();
  workers_.join();
}

Status Server::NotLeader(const std::string& what) const {
  const std::string leader = db_->Leader();
  return Status::NotLeader(what + ": this server only reads (it follows the writer's commits); "
                           "send writes to the writer" +
                           (leader.empty() ? std::string(" (its address is not known yet)")
                                           : " at " + leader));
}

void Server::FollowLoop() {
  using Clock = std::chrono::steady_clock;
  auto next_takeover = Clock::now();
  std::string last_error;
  // Woken by the writer's watch events (LeaderWatchLoop); the interval is the safety net for
  // when that connection is down.
  std::thread watcher;
  if (config_.follow_events) watcher = std::thread([this] { LeaderWatchLoop(); });
  std::unique_lock<std::mutex> l(follow_mu_);
  for (;;) {
    follow_cv_.wait_for(l, std::chrono::milliseconds(config_.follow_interval_ms),
                        [this] { return follow_stop_ || follow_wake_; });
    if (follow_stop_) break;
    follow_wake_ = false;
    l.unlock();
    Status st = db_->Refresh();
    if (!st.ok() && st.ToString() != last_error) {
      Log(LogLevel::kWarn, "following the writer: " + st.ToString() + " (retrying)");
    }
    last_error = st.ok() ? "" : st.ToString();
    // The lock is free once the writer closed, or its lease ran out after it died.
    if (Clock::now() >= next_takeover) {
      next_takeover = Clock::now() + std::chrono::seconds(1);
      auto took = db_->TryPromote();
      if (!took.ok()) {
        Log(LogLevel::kError, "taking over as the writer failed: " + took.status().ToString());
      } else if (*took) {
        Status pub = db_->SetLeaderAddress(advertise_);
        Log(LogLevel::kInfo, "took over as the writer of " + config_.data_dir +
                                 " (the previous writer is gone); clients send writes to " +
                                 advertise_ + (pub.ok() ? "" : " (not published: " +
                                                                  pub.ToString() + ")"));
        l.lock();
        break;
      }
    }
    l.lock();
  }
  watch_stop_ = true;
  l.unlock();
  if (watcher.joinable()) watcher.join();
}

void Server::LeaderWatchLoop() {
  // A watch of every dataset on the writer (its LEADER address): each change it publishes wakes
  // FollowLoop, which reads it from the shared files at once instead of at the next interval.
  const auto pause = std::chrono::milliseconds(config_.follow_interval_ms);
  std::string logged;
  while (!watch_stop_) {
    const std::string leader = db_->Leader();
    client::Options o;
    Status st = leader.empty() ? Status::NotFound("the writer has published no address")
                               : client::ParseAddress(leader, &o);
    std::unique_ptr<client::Connection> conn;
    std::unique_ptr<client::WatchStream> watch;
    if (st.ok()) {
      // A writer that wants tokens takes ours (servers of one directory share a token file).
      if (!tokens_.empty()) o.token = tokens_.begin()->first;
      o.connect_timeout = std::chrono::milliseconds(1000);
      o.request_timeout = std::chrono::milliseconds(5000);
      auto c = client::Connection::Connect(o);
      st = c.status();
      if (c.ok()) {
        conn = std::move(c).value();
        auto w = conn->Watch("");
        st = w.status();
        if (w.ok()) watch = std::move(w).value();
      }
    }
    if (!st.ok()) {
      if (st.ToString() != logged) {
        Log(LogLevel::kInfo, "no watch on the writer (" + st.ToString() + "); following it every " +
                                 std::to_string(config_.follow_interval_ms) + " ms");
      }
      logged = st.ToString();
      std::unique_lock<std::mutex> l(follow_mu_);
      follow_cv_.wait_for(l, pause, [this] { return watch_stop_.load() || follow_stop_; });
      continue;
    }
    logged.clear();
    ChangeEvent ev;
    while (!watch_stop_) {
      auto got = watch->Next(&ev, std::chrono::milliseconds(200));
      if (!got.ok() || watch->ended()) break;  // the writer went away or we lagged: look again
      if (*got && ev.kind != ChangeEvent::Kind::kLive) {
        {
          std::lock_guard<std::mutex> l(follow_mu_);
          follow_wake_ = true;
        }
        follow_cv_.notify_all();
      }
      if (db_->Leader() != leader) break;  // a new writer
    }
  }
}

std::string DefaultWebRoot() {
  namespace fs = std::filesystem;
  std::error_code ec;
  // A binary in its build tree serves the source tree's web/; an installed one its package's
  // share/hvdb/web, found next to its bin/ (so a relocated install works too).
  fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  if (!ec && exe.string().rfind(std::string(HVDB_BUILD_ROOT) + "/", 0) == 0) {
    return HVDB_SOURCE_WEB_ROOT;
  }
  if (!ec) {
    fs::path beside = exe.parent_path().parent_path() / "share" / "hvdb" / "web";
    if (fs::is_regular_file(beside / "index.html", ec)) return beside.string();
  }
  return HVDB_INSTALLED_WEB_ROOT;
}

uint16_t Server::http_port() const { return http_ ? http_->port() : 0; }
std::string Server::web_root() const { return http_ ? http_->web_root() : ""; }

size_t DefaultMemoryBudget() { return static_cast<size_t>(hvdb::DefaultMemoryBudget()); }

// "TOKEN ro|rw" lines ('#' comments, blank lines). A file that grants nothing would leave the
// server open to everyone, so it is refused, as is a token listed twice (which role was meant?).
static Result<std::map<std::string, Role>> ReadTokenFile(const std::string& path) {
  std::error_code fec;
  if (std::filesystem::is_directory(path, fec)) {
    return Status::InvalidArgument("--token-file " + path + " is a directory; give a file of "
                                   "'TOKEN ro|rw' lines");
  }
  std::ifstream in(path);
  if (!in) return Status::NotFound("--token-file: cannot read " + path);
  std::map<std::string, Role> tokens;
  std::map<std::string, int> first_line;
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    ++n;
    const size_t start = line.find_first_not_of(" \t\r");
    if (start == std::string::npos || line[start] == '#') continue;
    std::istringstream ls(line);
    std::string tok, role, extra;
    ls >> tok >> role >> extra;
    if (tok.size() < 16 || (role != "ro" && role != "rw") || !extra.empty()) {
      return Status::InvalidArgument(path + " line " + std::to_string(n) +
                                     ": expected 'TOKEN ro|rw' with a token of 16+ characters");
    }
    auto [it, fresh] = first_line.emplace(tok, n);
    if (!fresh) {
      return Status::InvalidArgument(path + " line " + std::to_string(n) +
                                     ": this token is already given on line " +
                                     std::to_string(it->second) +
                                     "; list each token once, with one role");
    }
    tokens[tok] = role == "rw" ? Role::kReadWrite : Role::kReadOnly;
  }
  if (in.bad()) return Status::IOError("--token-file: cannot read " + path);
  if (tokens.empty()) {
    return Status::InvalidArgument("--token-file " + path + " has no tokens: the server would "
                                   "let everyone in; add 'TOKEN ro|rw' lines (tokens of 16+ "
                                   "characters) or leave out --token-file");
  }
  return tokens;
}

static bool ParseHostPort(const std::string& s, std::string* host, uint16_t* port) {
  auto colon = s.rfind(':');
  if (colon == std::string::npos) return false;
  *host = s.substr(0, colon);
  if (host->size() > 2 && host->front() == '[' && host->back() == ']') {
    *host = host->substr(1, host->size() - 2);
  }
  try {
    int p = std::stoi(s.substr(colon + 1));
    if (p < 0 || p > 65535) return false;
    *port = static_cast<uint16_t>(p);
  } catch (...) {
    return false;
  }
  return true;
}

Result<std::unique_ptr<Server>> Server::Create(const Config& config) {
  // --listen: at most one HOST:PORT and at most one unix:PATH.
  std::string tcp_listen, local_socket;
  bool non_loopback = false;
  for (const std::string& l : config.listen) {
    if (l.rfind("unix:", 0) == 0) {
      if (!local_socket.empty()) return Status::InvalidArgument("--listen: more than one unix:PATH");
      std::string path = l.substr(5).empty() ? config.data_dir + "/hvdb.sock" : l.substr(5);
      std::error_code fec;
      auto abs = std::filesystem::absolute(path, fec);
      local_socket = fec ? path : abs.lexically_normal().string();
      if (local_socket.size() >= sizeof(sockaddr_un{}.sun_path)) {
        return Status::InvalidArgument("--listen unix:" + local_socket + ": a Unix socket path "
                                       "has at most " +
                                       std::to_string(sizeof(sockaddr_un{}.sun_path) - 1) +
                                       " characters; give a shorter one (unix:/tmp/hvdb.sock)");
      }
      continue;
    }
    if (!tcp_listen.empty()) return Status::InvalidArgument("--listen: more than one HOST:PORT");
    std::string host;
    uint16_t port;
    if (!ParseHostPort(l, &host, &port)) {
      return Status::InvalidArgument("--listen: expected HOST:PORT or unix:PATH, got '" + l + "'");
    }
    boost::system::error_code ec;
    auto addr = asio::ip::make_address(host, ec);
    if (ec) return Status::InvalidArgument("--listen: '" + host + "' is not an IP address");
    non_loopback = !addr.is_loopback();
    tcp_listen = l;
  }
  if (tcp_listen.empty() && local_socket.empty()) {
    return Status::InvalidArgument("--listen: give at least one HOST:PORT or unix:PATH");
  }
  std::map<std::string, Role> tokens;
  if (!config.token_file.empty()) {
    HVDB_ASSIGN_OR_RETURN(tokens, ReadTokenFile(config.token_file));
  }
  if (non_loopback && tokens.empty()) {
    return Status::InvalidArgument("--listen " + tcp_listen +
                                   " is not a loopback address: give --token-file so that "
                                   "clients must authenticate");
  }
  std::string http_host;
  uint16_t http_port = 0;
  if (!config.http_listen.empty()) {
    if (!ParseHostPort(config.http_listen, &http_host, &http_port)) {
      return Status::InvalidArgument("--http: expected HOST:PORT, got '" + config.http_listen + "'");
    }
    boost::system::error_code ec;
    auto addr = asio::ip::make_address(http_host, ec);
    if (ec) return Status::InvalidArgument("--http: '" + http_host + "' is not an IP address");
    if (!addr.is_loopback() && tokens.empty()) {
      return Status::InvalidArgument("--http " + config.http_listen +
                                     " is not a loopback address: give --token-file so that "
                                     "the WebSocket's clients must authenticate");
    }
  }
  Options opts;
  opts.cache_bytes = config.cache_mb << 20;
  opts.sync = config.sync;
  opts.max_slice_frames = config.max_slice_frames;
  opts.follow = config.follow;
  // Trees a checkpoint replaces outlive it by this much, for the queries of reading servers
  // that still read the state before it.
  opts.retired_grace_ms = config.follow ? 30000 : 0;
  opts.cold_after_s = config.cold_after_s;
  std::unique_ptr<Env> store_env;
  if (!config.store.empty()) {
    RadosSpec spec;
    HVDB_RETURN_IF_ERROR(ParseRadosSpec(config.store, &spec));
    HVDB_ASSIGN_OR_RETURN(store_env, OpenRadosEnv(spec));
    opts.env = store_env.get();
    // The data directory is a name prefix in the pool; the Unix socket still needs a folder.
    if (!local_socket.empty()) {
      std::error_code ec;
      std::filesystem::create_directories(std::filesystem::path(local_socket).parent_path(), ec);
    }
  }
  auto opened = Database::Open(config.data_dir, opts);
  if (!opened.ok()) return opened.status();
  std::unique_ptr<Server> s(new Server(config, std::move(opened).value()));
  s->store_env_ = std::move(store_env);
  s->tokens_ = std::move(tokens);
  s->require_token_ = !s->tokens_.empty();
  s->budget_ = config.memory_budget != 0 ? config.memory_budget : DefaultMemoryBudget();
  s->tcp_listen_ = tcp_listen;
  s->local_socket_ = local_socket;
  HVDB_RETURN_IF_ERROR(s->Listen());
  s->advertise_ = config.advertise;
  if (s->advertise_.empty()) {
    s->advertise_ = !tcp_listen.empty()
                        ? tcp_listen.substr(0, tcp_listen.rfind(':') + 1) + std::to_string(s->port_)
                        : "unix:" + local_socket;
  }
  if (!s->db_->follower()) {
    HVDB_RETURN_IF_ERROR(s->db_->SetLeaderAddress(s->advertise_));
  } else {
    const std::string leader = s->db_->Leader();
    Log(LogLevel::kInfo, "another server writes " + config.data_dir +
                             (leader.empty() ? "" : " (at " + leader + ")") +
                             ": serving reads and following its commits until it is gone");
    s->follower_ = std::thread([p = s.get()] { p->FollowLoop(); });
  }
  if (!config.http_listen.empty()) {
    HVDB_ASSIGN_OR_RETURN(
        s->http_, HttpFrontend::Create(s.get(), http_host, http_port,
                                       config.web_root.empty() ? DefaultWebRoot() : config.web_root,
                                       config.http_origins));
  }
  // The bound ports: the protocol's, then, with --http, the web viewer's on a second line.
  // Written whole, then renamed: a reader never sees half of it.
  if (!config.port_file.empty()) {
    const std::string tmp = config.port_file + ".tmp";
    {
      std::ofstream out(tmp);
      out << s->port_ << "\n";
      if (s->http_) out << s->http_->port() << "\n";
    }
    std::error_code fec;
    std::filesystem::rename(tmp, config.port_file, fec);
    if (fec) return Status::IOError("--port-file " + config.port_file + ": " + fec.message());
  }
  return s;
}

Status Server::Listen() {
  if (!local_socket_.empty()) HVDB_RETURN_IF_ERROR(ListenUnix(local_socket_));
  if (!tcp_listen_.empty()) {
    std::string host;
    uint16_t port;
    ParseHostPort(tcp_listen_, &host, &port);
    tcp::endpoint ep(asio::ip::make_address(host), port);
    boost::system::error_code ec;
    acceptor_.open(ep.protocol(), ec);
    if (!ec) acceptor_.set_option(tcp::acceptor::reuse_address(true), ec);
    if (!ec) acceptor_.bind(ep, ec);
    if (!ec) acceptor_.listen(asio::socket_base::max_listen_connections, ec);
    if (ec) return Status::IOError("listen on " + tcp_listen_ + ": " + ec.message());
    port_ = acceptor_.local_endpoint().port();
  }
  return Status::OK();
}

Status Server::ListenUnix(const std::string& path) {
  using local = asio::local::stream_protocol;
  struct stat st {};
  if (::lstat(path.c_str(), &st) == 0) {
    if (!S_ISSOCK(st.st_mode)) {
      return Status::InvalidArgument("--listen unix:" + path + ": the path exists and is not a "
                                     "socket; give another path");
    }
    // A socket file left by a server that was killed is removed; a live one is not ours.
    local::socket probe(io_);
    boost::system::error_code ec;
    probe.connect(local::endpoint(path), ec);
    if (!ec) {
      return Status::IOError("--listen unix:" + path + ": another server is listening there");
    }
    ::unlink(path.c_str());
  }
  boost::system::error_code ec;
  unix_acceptor_.open(local(), ec);
  if (!ec) unix_acceptor_.bind(local::endpoint(path), ec);
  if (!ec) unix_acceptor_.listen(asio::socket_base::max_listen_connections, ec);
  if (ec) return Status::IOError("listen on unix:" + path + ": " + ec.message());
  return Status::OK();
}

Role Server::Authenticate(const std::string& token) {
  if (!require_token_) return Role::kReadWrite;
  auto it = tokens_.find(token);
  if (it != tokens_.end()) return it->second;
  // Logged for whoever watches for guessing, at most once a second with a count of the rest.
  auto now = std::chrono::steady_clock::now();
  std::lock_guard<std::mutex> l(auth_log_mu_);
  ++auth_failures_unlogged_;
  if (now - last_auth_log_ >= std::chrono::seconds(1)) {
    Log(LogLevel::kWarn, "refused " + std::to_string(auth_failures_unlogged_) +
                             " connection(s) with a missing or unknown token" +
                             (token.empty() ? " (the last gave none)" : ""));
    auth_failures_unlogged_ = 0;
    last_auth_log_ = now;
  }
  return Role::kNone;
}

void Server::Accept() {
  Strand strand = asio::make_strand(io_);
  acceptor_.async_accept(strand, [this, strand](boost::system::error_code ec, tcp::socket socket) {
    if (ec) {
      if (!stopping_) {
        Log(LogLevel::kWarn, "accept: " + ec.message());
        Accept();
      }
      return;
    }
    boost::system::error_code ignored;
    socket.set_option(tcp::no_delay(true), ignored);
    auto peer = socket.remote_endpoint(ignored);
    const bool loopback = !ignored && peer.address().is_loopback();
    Admit(std::make_shared<Session>(
        this, strand, MakeStreamTransport(StreamSocket(std::move(socket)), strand,
                                          config_.max_frame_bytes),
        false, loopback));
    Accept();
  });
}

void Server::AcceptUnix() {
  Strand strand = asio::make_strand(io_);
  unix_acceptor_.async_accept(strand, [this, strand](boost::system::error_code ec,
                                                     asio::local::stream_protocol::socket socket) {
    if (ec) {
      if (!stopping_) {
        Log(LogLevel::kWarn, "accept on unix:" + local_socket_ + ": " + ec.message());
        AcceptUnix();
      }
      return;
    }
    Admit(std::make_shared<Session>(
        this, strand, MakeStreamTransport(StreamSocket(std::move(socket)), strand,
                                          config_.max_frame_bytes),
        true, false));
    AcceptUnix();
  });
}

void Server::Admit(std::shared_ptr<Session> session) {
  bool refuse = false, late = false;
  std::shared_ptr<Session> evicted;
  {
    std::lock_guard<std::mutex> l(mu_);
    late = stopping_.load();  // e.g. a WebSocket whose handshake ended after Stop took its list
    refuse = !late && authenticated_ >= config_.max_connections;
    if (!late && !refuse) {
      // A full pre-authentication pool makes room by closing the connection there longest:
      // a real client says Hello within milliseconds, a squatter never does.
      while (preauth_.size() >= config_.max_preauth && !evicted) {
        evicted = preauth_.front().lock();
        preauth_.pop_front();
      }
      preauth_.push_back(session);
    }
    if (!late) sessions_.insert(session);
  }
  // Started and closed outside mu_: a session's close may run inline (the caller can be on its
  // strand, as the WebSocket upgrade is) and takes mu_ to leave the list.
  session->Start();
  if (late) return session->Close();
  if (evicted) {
    Log(LogLevel::kDebug, "closed the oldest connection without a Hello (the pool of " +
                              std::to_string(config_.max_preauth) + " is full)");
    evicted->Close();
  }
  if (refuse) {
    session->Refuse(AtConnectionLimit());
  }
}

Status Server::AtConnectionLimit() const {
  return Status::Overloaded("the server has " + std::to_string(config_.max_connections) +
                            " connections, its limit; retry later");
}

bool Server::Authenticated(Session* s) {
  std::lock_guard<std::mutex> l(mu_);
  for (auto it = preauth_.begin(); it != preauth_.end(); ++it) {
    auto p = it->lock();
    if (p.get() == s) {
      preauth_.erase(it);
      if (authenticated_ >= config_.max_connections) return false;
      ++authenticated_;
      return true;
    }
  }
  return false;  // closed meanwhile (evicted)
}

void Server::Forget(Session* s, size_t freed) {
  {
    std::lock_guard<std::mutex> l(mu_);
    for (auto it = preauth_.begin(); it != preauth_.end(); ++it) {
      if (it->lock().get() == s) {
        preauth_.erase(it);
        break;
      }
    }
    for (auto it = sessions_.begin(); it != sessions_.end(); ++it) {
      if (it->get() == s) {
        if ((*it)->authenticated()) --authenticated_;
        sessions_.erase(it);
        break;
      }
    }
  }
  // Only worth a trim when closed connections held results (not for a flood of empty ones).
  if ((freed_since_trim_ += freed) >= kTrimAfterBytes) TrimSoon();
}

void Server::TrimSoon() {
  // A closed connection's buffers go back to malloc, which keeps them; whole free pages go back
  // to the OS half a second later (one trim for a wave of closes), off the network threads.
  if (stopping_ || trim_pending_.exchange(true)) return;
  freed_since_trim_ = 0;
  asio::dispatch(trim_timer_.get_executor(), [this] {
    trim_timer_.expires_after(std::chrono::milliseconds(500));
    trim_timer_.async_wait([this](boost::system::error_code ec) {
      trim_pending_ = false;
      if (!ec && !stopping_) asio::post(workers_, [] { ::malloc_trim(0); });
    });
  });
}

void Server::Run(bool handle_signals) {
  if (handle_signals) {
    signals_.add(SIGINT);
    signals_.add(SIGTERM);
    signals_.async_wait([this](boost::system::error_code ec, int sig) {
      if (ec) return;
      Log(LogLevel::kInfo, std::string("received ") + (sig == SIGINT ? "SIGINT" : "SIGTERM") +
                               ": shutting down");
      Stop();
    });
  }
  if (acceptor_.is_open()) {
    Accept();
    Log(LogLevel::kInfo, "hvdb-server listening on " +
                             acceptor_.local_endpoint().address().to_string() + ":" +
                             std::to_string(port_) + ", data " + config_.data_dir);
  }
  if (unix_acceptor_.is_open()) {
    AcceptUnix();
    Log(LogLevel::kInfo, "hvdb-server listening on unix:" + local_socket_ + " (local fast path)");
  }
  if (http_) {
    http_->Start();
    Log(LogLevel::kInfo, "web viewer on http://" + config_.http_listen.substr(0, config_.http_listen.rfind(':')) +
                             ":" + std::to_string(http_->port()) + "/ (files from " +
                             http_->web_root() + ")");
  }
  std::vector<std::thread> threads;
  for (unsigned i = 1; i < config_.io_threads; ++i) threads.emplace_back([this] { io_.run(); });
  io_.run();
  for (auto& t : threads) t.join();
  // Queries and commits still on the workers finish (cancelled queries end at once).
  workers_.join();
  if (!local_socket_.empty()) ::unlink(local_socket_.c_str());
  Log(LogLevel::kInfo, "stopped");
}

void Server::Stop() {
  if (stopping_.exchange(true)) return;
  asio::post(io_, [this] {
    boost::system::error_code ignored;
    acceptor_.close(ignored);
    unix_acceptor_.close(ignored);
    if (http_) http_->Stop();
    signals_.cancel(ignored);
    asio::dispatch(trim_timer_.get_executor(), [this] { trim_timer_.cancel(); });
    std::set<std::shared_ptr<Session>> all;
    {
      std::lock_guard<std::mutex> l(mu_);
      all = sessions_;
    }
    for (const auto& s : all) s->Close();
  });
}

}  // namespace hvdb::server
