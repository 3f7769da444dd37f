// What one request's job may hold: memory counted against a process-wide budget, and time.
//
// Import and render jobs decode what a client sends (pictures, videos, meshes) and build point
// buffers and images whose size a few header bytes can set. Each such buffer is reserved here
// before it is allocated, so that one small request cannot take the process's memory: a
// reservation over the budget fails with LimitExceeded naming the limit (hvdb-server:
// --memory-budget; embedded: 1/8 of the machine's memory) and nothing is allocated. The job's
// deadline (hvdb-server: --max-job-seconds) is checked between units of work (a video frame,
// a batch of samples, an image of a sequence).
//
// Thread safety: a JobBudget is shared by all jobs of a process (atomic counter); a JobLease
// and a JobLimits belong to one job.
#ifndef HVDB_STORAGE_JOB_LIMITS_H_
#define HVDB_STORAGE_JOB_LIMITS_H_

#include <atomic>
#include <chrono>
#include <cstdint>
#include <string>

#include "storage/status.h"

namespace hvdb {

// 1/8 of the machine's physical memory (at least 64 MiB): hvdb-server's --memory-budget default.
uint64_t DefaultMemoryBudget();

class JobBudget {
 public:
  // `limit_name` names the setting in errors ("--memory-budget").
  JobBudget(uint64_t limit_bytes, std::string limit_name)
      : limit_(limit_bytes), name_(std::move(limit_name)) {}
  JobBudget(const JobBudget&) = delete;
  JobBudget& operator=(const JobBudget&) = delete;

  uint64_t limit() const { return limit_; }
  uint64_t used() const { return used_.load(std::memory_order_relaxed); }
  const std::string& limit_name() const { return name_; }

  // Takes `bytes` if the total stays within the limit; else LimitExceeded:
  // "<what> needs N MiB, over the memory budget (--memory-budget: L MiB, U MiB held by other
  // jobs)".
  Status Take(uint64_t bytes, const std::string& what);
  void Give(uint64_t bytes) { used_.fetch_sub(bytes, std::memory_order_relaxed); }

 private:
  const uint64_t limit_;
  const std::string name_;
  std::atomic<uint64_t> used_{0};
};

// One job's share of a JobBudget, given back when the lease is destroyed. Reserve() grows it;
// a lease without a budget (JobLimits{}) counts nothing and never refuses.
class JobLease {
 public:
  JobLease() = default;
  explicit JobLease(JobBudget* budget) : budget_(budget) {}
  JobLease(JobLease&& o) noexcept : budget_(o.budget_), held_(o.held_) { o.held_ = 0; }
  JobLease& operator=(JobLease&& o) noexcept;
  JobLease(const JobLease&) = delete;
  JobLease& operator=(const JobLease&) = delete;
  ~JobLease() { Reset(); }

  Status Reserve(uint64_t bytes, const std::string& what);
  // Gives back `bytes` of what this lease holds (a buffer freed before the job ends).
  void Release(uint64_t bytes);
  void Reset();
  uint64_t held() const { return held_; }

 private:
  JobBudget* budget_ = nullptr;
  uint64_t held_ = 0;
};

// The bounds a request's job runs under. Default: no budget, no deadline (tests, tools).
struct JobLimits {
  JobBudget* memory = nullptr;
  uint32_t max_seconds = 0;  // 0: no deadline
  std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();

  // LimitExceeded "<what>: over the time limit of a job (--max-job-seconds: N s)" once
  // max_seconds have passed since `start`.
  Status CheckTime(const std::string& what) const;
  JobLease Lease() const { return JobLease(memory); }
};

}  // namespace hvdb

#endif  // HVDB_STORAGE_JOB_LIMITS_H_
