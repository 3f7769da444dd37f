// The local fast path's shared memory (docs/PROTOCOL.md, "The local fast path"): a ring of
// fixed-size slots in a sealed memfd that hvdb-server writes query results into and the client
// maps read-only, and the SCM_RIGHTS calls that hand its descriptor over the Unix socket.
#ifndef HVDB_PROTOCOL_SHM_H_
#define HVDB_PROTOCOL_SHM_H_

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>

#include "storage/status.h"

namespace hvdb::wire {

class ShmRing {
 public:
  // Server: a new memfd of slots x slot_bytes, mapped read-write, sealed so that the client
  // can neither shrink it (which would fault the server's writes) nor map it writable.
  static Result<std::unique_ptr<ShmRing>> Create(uint32_t slots, uint32_t slot_bytes);
  // Client: maps a received descriptor read-only (takes ownership of fd); checks its size.
  static Result<std::unique_ptr<ShmRing>> Map(int fd, uint32_t slots, uint32_t slot_bytes);
  ~ShmRing();
  ShmRing(const ShmRing&) = delete;
  ShmRing& operator=(const ShmRing&) = delete;

  int fd() const { return fd_; }
  uint32_t slots() const { return slots_; }
  uint32_t slot_bytes() const { return slot_bytes_; }
  uint8_t* slot(uint32_t i) const { return base_ + static_cast<size_t>(i) * slot_bytes_; }

 private:
  ShmRing(int fd, uint8_t* base, uint32_t slots, uint32_t slot_bytes)
      : fd_(fd), base_(base), slots_(slots), slot_bytes_(slot_bytes) {}
  int fd_;
  uint8_t* base_;
  uint32_t slots_, slot_bytes_;
};

// Sends all of `data` on a connected Unix stream socket, with `fd` attached to its first byte
// (SCM_RIGHTS). Waits at most `timeout` for room in the socket's buffer.
Status SendWithFd(int sock, const std::string& data, int fd, std::chrono::milliseconds timeout);
// Receives exactly n bytes; a descriptor that came with them is stored in *fd (else -1; a
// second one is closed). Waits at most `timeout` in all.
Status RecvWithFd(int sock, uint8_t* buf, size_t n, int* fd, std::chrono::milliseconds timeout);

}  // namespace hvdb::wire

#endif  // HVDB_PROTOCOL_SHM_H_
