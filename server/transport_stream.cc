// The stream transport: length-prefixed protobuf frames over a TCP or Unix-domain socket
// (docs/PROTOCOL.md, "Framing").
#include "server/transport.h"

#include <algorithm>

namespace hvdb::server {

namespace asio = boost::asio;

namespace {

class StreamTransport : public Transport, public std::enable_shared_from_this<StreamTransport> {
 public:
  StreamTransport(StreamSocket socket, Strand strand, uint32_t max_frame)
      : socket_(std::move(socket)), strand_(std::move(strand)), max_frame_(max_frame) {}

  void Read(wire::Hello* hello, wire::Request* request, ReadDone done) override {
    auto self = shared_from_this();
    asio::async_read(
        socket_, asio::buffer(header_),
        asio::bind_executor(strand_, [self, hello, request, done = std::move(done)](
                                         boost::system::error_code ec, size_t) mutable {
          if (ec) return done(ec, Status::OK(), 0);
          uint32_t len;
          bool attachment = false;
          // Before the Hello only a Hello's worth: a connection that has not authenticated
          // cannot make the server allocate a large frame.
          const uint32_t limit = hello != nullptr ? std::min(self->max_frame_, kMaxHelloBytes)
                                                  : self->max_frame_;
          if (!wire::ParseFrameHeader(self->header_, limit, &len, &attachment)) {
            return done({}, Status::InvalidArgument(
                                "frame of " + std::to_string(len) + " bytes exceeds the limit of " +
                                std::to_string(limit) + (hello ? " for a Hello" : "")),
                        wire::kFrameHeaderSize);
          }
          if (attachment) {
            return done({}, Status::InvalidArgument(
                                "a client frame may not carry an attachment (bit 31 of the "
                                "length word)"),
                        wire::kFrameHeaderSize);
          }
          self->ReadBody(len, hello, request, std::move(done));
        }));
  }

  OutFrame Encode(const google::protobuf::Message& m, std::vector<Point> records,
                  size_t count) override {
    OutFrame f;
    if (count > 0) {
      f.head = wire::FrameHead(m, static_cast<uint32_t>(count * sizeof(Point)));
      f.records = std::move(records);
      f.count = count;
    } else {
      f.head = wire::Frame(m);
    }
    return f;
  }

  void Write(const std::deque<OutFrame>& out, WriteDone done) override {
    // Every frame queued so far in one gather write (a batch and its QueryDone, a task's
    // batches): one system call and one completion instead of one per frame.
    std::vector<asio::const_buffer> bufs;
    size_t frames = 0, bytes = 0;
    for (const OutFrame& f : out) {
      // At most ~4 MiB a write (one frame at least): each completion is progress the session
      // sees, so a slow reader is told apart from one that does not read.
      if (frames == kMaxGather || (frames > 0 && bytes + f.bytes() > kMaxGatherBytes)) break;
      bytes += f.bytes();
      bufs.push_back(asio::buffer(f.head));
      if (f.count > 0) bufs.push_back(asio::buffer(f.records.data(), f.count * sizeof(Point)));
      ++frames;
    }
    auto self = shared_from_this();
    asio::async_write(socket_, bufs,
                      asio::bind_executor(strand_, [self, frames, done = std::move(done)](
                                                       boost::system::error_code ec, size_t n) {
                        done(ec, frames, n);
                      }));
  }

  void Close() override {
    boost::system::error_code ignored;
    socket_.shutdown(StreamSocket::shutdown_both, ignored);
    socket_.close(ignored);
  }

  int native_handle() override { return socket_.native_handle(); }

 private:
  static constexpr size_t kMaxGather = 32;  // frames in one gather write
  static constexpr size_t kMaxGatherBytes = 4u << 20;
  static constexpr size_t kKeepBodyBytes = 64u << 10;

  void ReadBody(uint32_t len, wire::Hello* hello, wire::Request* request, ReadDone done) {
    body_.resize(len);
    auto self = shared_from_this();
    asio::async_read(
        socket_, asio::buffer(body_),
        asio::bind_executor(strand_, [self, hello, request, done = std::move(done)](
                                         boost::system::error_code ec, size_t n) {
          if (ec) return done(ec, Status::OK(), 0);
          const size_t bytes = n + wire::kFrameHeaderSize;
          if (hello != nullptr) {
            if (!hello->ParseFromString(self->body_)) {
              return done({}, Status::InvalidArgument("the first frame must be a Hello message"),
                          bytes);
            }
          } else if (!request->ParseFromString(self->body_)) {
            return done({}, Status::InvalidArgument("request frame is not a valid Request message"),
                        bytes);
          }
          // A large request's buffer is not kept for the connection's lifetime.
          if (self->body_.capacity() > kKeepBodyBytes) std::string().swap(self->body_);
          done({}, Status::OK(), bytes);
        }));
  }

  StreamSocket socket_;
  Strand strand_;
  const uint32_t max_frame_;
  uint8_t header_[wire::kFrameHeaderSize];
  std::string body_;
};

}  // namespace

std::shared_ptr<Transport> MakeStreamTransport(StreamSocket socket, Strand strand,
                                               uint32_t max_frame_bytes) {
  return std::make_shared<StreamTransport>(std::move(socket), std::move(strand), max_frame_bytes);
}

}  // namespace hvdb::server
