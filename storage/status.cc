#include "storage/status.h"

#include <cstring>

namespace hvdb {

const char* StatusCodeName(StatusCode code) {
  switch (code) {
    case StatusCode::kOk: return "OK";
    case StatusCode::kNotFound: return "NotFound";
    case StatusCode::kInvalidArgument: return "InvalidArgument";
    case StatusCode::kCorruption: return "Corruption";
    case StatusCode::kIOError: return "IOError";
    case StatusCode::kLimitExceeded: return "LimitExceeded";
    case StatusCode::kAlreadyExists: return "AlreadyExists";
    case StatusCode::kCancelled: return "Cancelled";
    case StatusCode::kInternal: return "Internal";
    case StatusCode::kPermissionDenied: return "PermissionDenied";
    case StatusCode::kOverloaded: return "Overloaded";
    case StatusCode::kUnsupported: return "Unsupported";
    case StatusCode::kNotLeader: return "NotLeader";
  }
  return "Unknown";
}

// GNU strerror_r returns the message pointer (which may or may not be buf); the XSI one (musl,
// as in the WebAssembly build of codec/) returns 0 and fills buf.
[[maybe_unused]] static const char* StrerrorText(const char* text, const char*) { return text; }
[[maybe_unused]] static const char* StrerrorText(int rc, const char* buf) {
  return rc == 0 ? buf : "unknown error";
}

Status Status::FromErrno(const std::string& context, int err) {
  char buf[256];
  const char* text = StrerrorText(strerror_r(err, buf, sizeof(buf)), buf);
  StatusCode code = err == ENOENT ? StatusCode::kNotFound : StatusCode::kIOError;
  std::string hint;
  if (err == ENOSPC) hint = " (the disk is full: free space and retry; nothing was committed)";
  if (err == EACCES || err == EPERM) hint = " (check the permissions of the data directory)";
  return {code, context + ": " + text + hint};
}

std::string Status::ToString() const {
  if (ok()) return "OK";
  return std::string(StatusCodeName(code_)) + ": " + msg_;
}

}  // namespace hvdb
