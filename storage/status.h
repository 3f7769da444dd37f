// Status and Result<T>: how every fallible storage function reports failure.
//
// The storage layer does not throw across its API (as in LevelDB): a function returns a
// Status, or a Result<T> holding either a value or a non-OK Status. An OK Status costs one
// byte and no allocation. Messages name the file, block or parameter at fault and, where
// there is one, the remedy.
#ifndef HVDB_STORAGE_STATUS_H_
#define HVDB_STORAGE_STATUS_H_

#include <cassert>
#include <optional>
#include <string>
#include <utility>

namespace hvdb {

enum class StatusCode : unsigned char {
  kOk = 0,
  kNotFound = 1,         // no such dataset, frame, point or file
  kInvalidArgument = 2,  // a parameter out of range; the message says which and why
  kCorruption = 3,       // a checksum or invariant failed; the message names file and block
  kIOError = 4,          // the OS refused (disk full, permission, ...); errno text included
  kLimitExceeded = 5,    // a configured bound (frames per slice, memory, ...) would be passed
  kAlreadyExists = 6,
  kCancelled = 7,
  kInternal = 8,
  kPermissionDenied = 9,  // the caller's role does not allow it (server)
  kOverloaded = 10,       // too many requests or connections; retry later (server)
  kUnsupported = 11,      // a version, capability or request this build does not have
  kNotLeader = 12,        // a follower refuses writes; the message names the writer
};

const char* StatusCodeName(StatusCode code);

// [[nodiscard]]: an error dropped on the floor is a bug; a caller that means to ignore one
// says so with (void) and a reason.
class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(StatusCode code, std::string msg) : code_(code), msg_(std::move(msg)) {}

  static Status OK() { return {}; }
  static Status NotFound(std::string m) { return {StatusCode::kNotFound, std::move(m)}; }
  static Status InvalidArgument(std::string m) { return {StatusCode::kInvalidArgument, std::move(m)}; }
  static Status Corruption(std::string m) { return {StatusCode::kCorruption, std::move(m)}; }
  static Status IOError(std::string m) { return {StatusCode::kIOError, std::move(m)}; }
  static Status LimitExceeded(std::string m) { return {StatusCode::kLimitExceeded, std::move(m)}; }
  static Status AlreadyExists(std::string m) { return {StatusCode::kAlreadyExists, std::move(m)}; }
  static Status Cancelled(std::string m) { return {StatusCode::kCancelled, std::move(m)}; }
  static Status Internal(std::string m) { return {StatusCode::kInternal, std::move(m)}; }
  static Status PermissionDenied(std::string m) { return {StatusCode::kPermissionDenied, std::move(m)}; }
  static Status Overloaded(std::string m) { return {StatusCode::kOverloaded, std::move(m)}; }
  static Status Unsupported(std::string m) { return {StatusCode::kUnsupported, std::move(m)}; }
  static Status NotLeader(std::string m) { return {StatusCode::kNotLeader, std::move(m)}; }
  // errno mapped in one place: "context: strerror(err)".
  static Status FromErrno(const std::string& context, int err);

  bool ok() const { return code_ == StatusCode::kOk; }
  StatusCode code() const { return code_; }
  const std::string& message() const { return msg_; }
  bool IsNotFound() const { return code_ == StatusCode::kNotFound; }
  bool IsCorruption() const { return code_ == StatusCode::kCorruption; }
  bool IsInvalidArgument() const { return code_ == StatusCode::kInvalidArgument; }
  // "Corruption: wal.log record 12: checksum mismatch"
  std::string ToString() const;

 private:
  StatusCode code_ = StatusCode::kOk;
  std::string msg_;
};

// A value or an error. REQUIRES: the Status given is not OK.
template <typename T>
class [[nodiscard]] Result {
 public:
  Result(T value) : value_(std::move(value)) {}  // NOLINT(google-explicit-constructor)
  Result(Status status) : status_(std::move(status)) {  // NOLINT(google-explicit-constructor)
    assert(!status_.ok());
  }
  bool ok() const { return value_.has_value(); }
  const Status& status() const { return status_; }
  T& value() & { return *value_; }
  const T& value() const& { return *value_; }
  T&& value() && { return std::move(*value_); }
  T* operator->() { return &*value_; }
  const T* operator->() const { return &*value_; }
  T& operator*() { return *value_; }

 private:
  std::optional<T> value_;
  Status status_;
};

}  // namespace hvdb

#define HVDB_RETURN_IF_ERROR(expr)          \
  do {                                      \
    ::hvdb::Status _hvdb_st = (expr);       \
    if (!_hvdb_st.ok()) return _hvdb_st;    \
  } while (0)

#define HVDB_CONCAT_INNER_(a, b) a##b
#define HVDB_CONCAT_(a, b) HVDB_CONCAT_INNER_(a, b)
#define HVDB_ASSIGN_OR_RETURN(lhs, expr) \
  HVDB_ASSIGN_OR_RETURN_IMPL_(HVDB_CONCAT_(_hvdb_res_, __LINE__), lhs, expr)
#define HVDB_ASSIGN_OR_RETURN_IMPL_(res, lhs, expr) \
  auto res = (expr);                                \
  if (!res.ok()) return res.status();               \
  lhs = std::move(res).value()

#endif  // HVDB_STORAGE_STATUS_H_
