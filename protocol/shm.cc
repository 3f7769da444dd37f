#include "protocol/shm.h"

#include <fcntl.h>
#include <poll.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace hvdb::wire {

namespace {

Status Errno(const std::string& what) {
  return Status::IOError(what + ": " + std::strerror(errno));
}

// Waits until `sock` is ready for `events` or the deadline passes.
Status WaitFor(int sock, short events, std::chrono::steady_clock::time_point deadline,
               const char* what) {
  for (;;) {
    auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) return Status::IOError(std::string(what) + ": timed out");
    pollfd p{sock, events, 0};
    int r = ::poll(&p, 1, static_cast<int>(left.count()));
    if (r > 0) return Status::OK();
    if (r < 0 && errno != EINTR) return Errno(what);
  }
}

}  // namespace

Result<std::unique_ptr<ShmRing>> ShmRing::Create(uint32_t slots, uint32_t slot_bytes) {
  if (slots == 0 || slot_bytes == 0) return Status::InvalidArgument("shm ring: empty");
  const size_t bytes = static_cast<size_t>(slots) * slot_bytes;
  int fd = ::memfd_create("hvdb-ring", MFD_CLOEXEC | MFD_ALLOW_SEALING);
  if (fd < 0) return Errno("memfd_create");
  if (::ftruncate(fd, static_cast<off_t>(bytes)) != 0) {
    Status st = Errno("ftruncate of the shared-memory ring");
    ::close(fd);
    return st;
  }
  void* p = ::mmap(nullptr, bytes, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
  if (p == MAP_FAILED) {
    Status st = Errno("mmap of the shared-memory ring");
    ::close(fd);
    return st;
  }
  // After F_SEAL_FUTURE_WRITE no new writable mapping can be made; ours stays writable.
  if (::fcntl(fd, F_ADD_SEALS, F_SEAL_SHRINK | F_SEAL_GROW | F_SEAL_FUTURE_WRITE | F_SEAL_SEAL) != 0) {
    Status st = Errno("sealing the shared-memory ring");
    ::munmap(p, bytes);
    ::close(fd);
    return st;
  }
  return std::unique_ptr<ShmRing>(new ShmRing(fd, static_cast<uint8_t*>(p), slots, slot_bytes));
}

Result<std::unique_ptr<ShmRing>> ShmRing::Map(int fd, uint32_t slots, uint32_t slot_bytes) {
  const size_t bytes = static_cast<size_t>(slots) * slot_bytes;
  struct stat st {};
  if (bytes == 0 || ::fstat(fd, &st) != 0 || static_cast<size_t>(st.st_size) != bytes) {
    ::close(fd);
    return Status::IOError("hvdb-server's shared-memory ring does not have the announced size");
  }
  // The server sealed it against shrinking, so reading it can never fault.
  int seals = ::fcntl(fd, F_GET_SEALS);
  if (seals < 0 || !(seals & F_SEAL_SHRINK)) {
    ::close(fd);
    return Status::IOError("hvdb-server's shared-memory ring is not sealed against shrinking");
  }
  void* p = ::mmap(nullptr, bytes, PROT_READ, MAP_SHARED, fd, 0);
  if (p == MAP_FAILED) {
    Status s = Errno("mmap of hvdb-server's shared-memory ring");
    ::close(fd);
    return s;
  }
  return std::unique_ptr<ShmRing>(new ShmRing(fd, static_cast<uint8_t*>(p), slots, slot_bytes));
}

ShmRing::~ShmRing() {
  ::munmap(base_, static_cast<size_t>(slots_) * slot_bytes_);
  ::close(fd_);
}

Status SendWithFd(int sock, const std::string& data, int fd, std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  size_t sent = 0;
  while (sent < data.size()) {
    iovec iov{const_cast<char*>(data.data() + sent), data.size() - sent};
    msghdr msg{};
    msg.msg_iov = &iov;
    msg.msg_iovlen = 1;
    alignas(cmsghdr) char control[CMSG_SPACE(sizeof(int))] = {};
    if (sent == 0) {
      msg.msg_control = control;
      msg.msg_controllen = sizeof(control);
      cmsghdr* c = CMSG_FIRSTHDR(&msg);
      c->cmsg_level = SOL_SOCKET;
      c->cmsg_type = SCM_RIGHTS;
      c->cmsg_len = CMSG_LEN(sizeof(int));
      std::memcpy(CMSG_DATA(c), &fd, sizeof(int));
    }
    ssize_t n = ::sendmsg(sock, &msg, MSG_NOSIGNAL);
    if (n > 0) {
      sent += static_cast<size_t>(n);
    } else if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR)) {
      HVDB_RETURN_IF_ERROR(WaitFor(sock, POLLOUT, deadline, "send with a descriptor"));
    } else {
      return Errno("send with a descriptor");
    }
  }
  return Status::OK();
}

Status RecvWithFd(int sock, uint8_t* buf, size_t n, int* fd, std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  *fd = -1;
  size_t got = 0;
  while (got < n) {
    iovec iov{buf + got, n - got};
    msghdr msg{};
    msg.msg_iov = &iov;
    msg.msg_iovlen = 1;
    alignas(cmsghdr) char control[CMSG_SPACE(sizeof(int) * 4)];
    msg.msg_control = control;
    msg.msg_controllen = sizeof(control);
    ssize_t r = ::recvmsg(sock, &msg, MSG_CMSG_CLOEXEC);
    if (r > 0) {
      got += static_cast<size_t>(r);
      for (cmsghdr* c = CMSG_FIRSTHDR(&msg); c; c = CMSG_NXTHDR(&msg, c)) {
        if (c->cmsg_level != SOL_SOCKET || c->cmsg_type != SCM_RIGHTS) continue;
        size_t count = (c->cmsg_len - CMSG_LEN(0)) / sizeof(int);
        for (size_t i = 0; i < count; ++i) {
          int f;
          std::memcpy(&f, CMSG_DATA(c) + i * sizeof(int), sizeof(int));
          if (*fd < 0) {
            *fd = f;
          } else {
            ::close(f);
          }
        }
      }
    } else if (r == 0) {
      return Status::IOError("hvdb-server closed the connection");
    } else if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR) {
      Status st = WaitFor(sock, POLLIN, deadline, "receive from hvdb-server");
      if (!st.ok()) {
        if (*fd >= 0) ::close(*fd);
        *fd = -1;
        return st;
      }
    } else {
      if (*fd >= 0) ::close(*fd);
      *fd = -1;
      return Errno("receive from hvdb-server");
    }
  }
  return Status::OK();
}

}  // namespace hvdb::wire
