// Session: one client connection. All socket I/O and session state live on the session's
// strand; request work runs on the server's worker pool and posts its responses back.
#ifndef HVDB_SERVER_SESSION_H_
#define HVDB_SERVER_SESSION_H_

#include <chrono>
#include <deque>
#include <map>
#include <set>
#include <memory>
#include <string>

#include <utility>  // before Asio: Boost 1.74's awaitable.hpp needs std::exchange

#include <boost/asio.hpp>

#include "protocol/wire.h"
#include "server/server.h"

namespace hvdb::server {

class Session : public std::enable_shared_from_this<Session> {
 public:
  Session(Server* server, boost::asio::ip::tcp::socket socket);
  void Start();
  // Closes the connection and cancels its requests. Safe from any thread.
  void Close();
  // Sends one error frame and closes (used for refused connections too).
  void Refuse(const Status& st);

 private:
  struct Op;  // an in-flight request
  using Clock = std::chrono::steady_clock;

  void ReadHeader();
  void ReadBody(uint32_t len);
  void OnFrame();
  void OnHello(const std::string& payload);
  void Dispatch(wire::Request req);
  void Send(const wire::Response& r);
  void SendError(uint64_t id, const Status& st, wire::ErrorCode code = wire::ERROR_UNSPECIFIED);
  void WriteNext();
  void ArmTimer();
  void CloseOnStrand();
  // Ends request `id`: records its latency and forgets it.
  void Finish(uint64_t id);
  // Query streaming: produce one batch on a worker, then decide on the strand.
  void Pump(std::shared_ptr<Op> op);
  void ResumePaused();
  // Runs fn on a worker; its response is sent and the request finished on the strand.
  void RunOnWorker(uint64_t id, std::function<wire::Response()> fn);
  void HandleIngest(uint64_t id, const wire::Ingest& ing);
  // Render requests: a slot of the server's renderer pool, then one image at a time on a
  // worker, sequences under the same flow control as queries.
  void HandleRender(std::shared_ptr<Op> op, const wire::Render& request);
  void RenderNext(std::shared_ptr<Op> op);

  Server* server_;
  boost::asio::ip::tcp::socket socket_;
  boost::asio::strand<boost::asio::io_context::executor_type> strand_;
  boost::asio::steady_timer timer_;
  Clock::time_point deadline_;
  uint8_t header_[wire::kFrameHeaderSize];
  std::string body_;
  bool hello_done_ = false;
  Role role_ = Role::kNone;
  bool closed_ = false;
  bool close_after_write_ = false;
  // Outbound frames; bytes_queued_ is what flow control looks at.
  std::deque<std::string> out_;
  size_t bytes_queued_ = 0;
  bool writing_ = false;
  std::map<uint64_t, std::shared_ptr<Op>> ops_;
  // Bulk ingest: points of frames whose last chunk has not come yet.
  std::map<std::pair<std::string, uint32_t>, std::vector<Point>> ingest_;
  size_t ingest_bytes_ = 0;
  std::set<std::pair<std::string, uint32_t>> ingest_failed_;  // until their `last` chunk
};

}  // namespace hvdb::server

#endif  // HVDB_SERVER_SESSION_H_
