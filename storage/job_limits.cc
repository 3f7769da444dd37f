#include "storage/job_limits.h"

#include <unistd.h>

#include <algorithm>

namespace hvdb {
namespace {

std::string Mib(uint64_t bytes) { return std::to_string((bytes + (1u << 20) - 1) >> 20) + " MiB"; }

}  // namespace

uint64_t DefaultMemoryBudget() {
  const long pages = ::sysconf(_SC_PHYS_PAGES);
  const long page = ::sysconf(_SC_PAGESIZE);
  if (pages <= 0 || page <= 0) return uint64_t{1} << 30;
  return std::max<uint64_t>(uint64_t{64} << 20, static_cast<uint64_t>(pages) * page / 8);
}

Status JobBudget::Take(uint64_t bytes, const std::string& what) {
  uint64_t cur = used_.load(std::memory_order_relaxed);
  do {
    if (bytes > limit_ || cur > limit_ - bytes) {
      return Status::LimitExceeded(what + " needs " + Mib(bytes) +
                                   ", over the memory budget of jobs (" + name_ + ": " +
                                   Mib(limit_) + ", " + Mib(cur) + " held by other jobs)");
    }
  } while (!used_.compare_exchange_weak(cur, cur + bytes, std::memory_order_relaxed));
  return Status::OK();
}

JobLease& JobLease::operator=(JobLease&& o) noexcept {
  if (this != &o) {
    Reset();
    budget_ = o.budget_;
    held_ = o.held_;
    o.held_ = 0;
  }
  return *this;
}

Status JobLease::Reserve(uint64_t bytes, const std::string& what) {
  if (budget_ == nullptr || bytes == 0) return Status::OK();
  // The job's own share counts against it too: "held by other jobs" then includes this one's
  // earlier reservations, which is what the number means to a reader of the error.
  HVDB_RETURN_IF_ERROR(budget_->Take(bytes, what));
  held_ += bytes;
  return Status::OK();
}

void JobLease::Release(uint64_t bytes) {
  bytes = std::min(bytes, held_);
  if (budget_ != nullptr) budget_->Give(bytes);
  held_ -= bytes;
}

void JobLease::Reset() {
  if (budget_ != nullptr && held_ != 0) budget_->Give(held_);
  held_ = 0;
}

Status JobLimits::CheckTime(const std::string& what) const {
  if (max_seconds == 0) return Status::OK();
  const auto elapsed = std::chrono::steady_clock::now() - start;
  if (elapsed < std::chrono::seconds(max_seconds)) return Status::OK();
  return Status::LimitExceeded(what + ": over the time limit of a job (--max-job-seconds: " +
                               std::to_string(max_seconds) + " s)");
}

}  // namespace hvdb
