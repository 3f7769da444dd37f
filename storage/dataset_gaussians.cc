// The Gaussian column of a dataset (storage/gaussian_column.h): loads with records, reads of
// them, and the records of splats an edit turns or scales.
#include <algorithm>
#include <thread>

#include "storage/dataset_impl.h"

namespace hvdb {

Result<uint64_t> DatasetImpl::BulkLoadGaussians(uint32_t frame, std::vector<Point> points,
                                                const GaussianColumns& attrs) {
  if (!gaussians_) {
    if (follower_.load()) return BulkLoad(frame, std::move(points));  // NotLeader, from Submit
    return Status::InvalidArgument("dataset '" + info_.name +
                                   "' holds plain points, not Gaussian splats: create it with "
                                   "--gaussians to load splat files");
  }
  if (attrs.size() != points.size() || attrs.values.size() != points.size() * attrs.stride()) {
    return Status::InvalidArgument("Gaussian load: " + std::to_string(points.size()) +
                                   " points but " + std::to_string(attrs.size()) + " records");
  }
  HVDB_RETURN_IF_ERROR(ValidateGaussianColumns(attrs));
  if (points.empty()) return BulkLoad(frame, std::move(points));
  if (follower_.load()) return BulkLoad(frame, std::move(points));  // NotLeader
  // Issue the ids first, write their records durably, then load the points: a crash between
  // leaves a segment whose ids recovery finds unissued (GaussianColumn::Open removes it).
  // The segment is written on a thread of its own while the frame's tree is built (both are
  // hundreds of MB for a million splats), and the tree is installed only once it is durable.
  const uint64_t first = next_id_.fetch_add(points.size());
  for (size_t i = 0; i < points.size(); ++i) points[i].id = first + i;
  Status written;
  std::thread writer([&] {
    try {
      written = gaussians_->Write(first, attrs);
    } catch (const std::bad_alloc&) {
      written = Status::LimitExceeded("Gaussian load: out of memory writing the records");
    } catch (const std::exception& e) {
      written = Status::Internal(std::string("Gaussian load: ") + e.what());
    }
  });
  // Joined on every way out, an exception of the load's included (a joinable thread's
  // destructor would end the process).
  struct Joiner {
    std::thread& t;
    ~Joiner() {
      if (t.joinable()) t.join();
    }
  } joiner{writer};
  auto join = [&] {
    if (writer.joinable()) writer.join();
    return written;
  };
  Result<uint64_t> loaded = BulkLoadThen(frame, std::move(points), join);
  (void)join();  // the load failed first: its error is the one reported
  if (!loaded.ok()) (void)gaussians_->Remove(first);  // the error reported is the load's
  return loaded;
}

Status DatasetImpl::ReadGaussianRecords(std::span<const uint64_t> ids, GaussianColumns* out,
                                        std::vector<bool>* found, size_t max_blocks) const {
  if (gaussians_) return gaussians_->Read(ids, out, found, max_blocks);
  *out = GaussianColumns{};
  out->values.assign(ids.size() * out->stride(), 0.f);
  found->assign(ids.size(), false);
  return Status::OK();
}

Result<GaussianColumns> DatasetImpl::ReadGaussians(std::span<const Point> points,
                                                   uint64_t* derived) const {
  std::vector<uint64_t> ids(points.size());
  for (size_t i = 0; i < points.size(); ++i) ids[i] = points[i].id;
  GaussianColumns out;
  std::vector<bool> found;
  HVDB_RETURN_IF_ERROR(ReadGaussianRecords(ids, &out, &found));
  const uint64_t n = DeriveMissing(points, found, &out);
  if (derived) *derived = n;
  return out;
}

Result<uint64_t> DatasetImpl::WriteInsertedGaussians(std::span<const Point> points,
                                                     const GaussianColumns& records,
                                                     std::vector<uint64_t>* segments) {
  if (records.size() != points.size() || records.values.size() != points.size() * records.stride()) {
    return Status::InvalidArgument("insert: " + std::to_string(points.size()) + " points but " +
                                   std::to_string(records.size()) + " Gaussian records");
  }
  HVDB_RETURN_IF_ERROR(ValidateGaussianColumns(records));
  for (const Point& p : points) {
    if (p.id != 0) {
      return Status::InvalidArgument("insert: point " + std::to_string(p.id) +
                                     " comes with a Gaussian record but is not new (id 0): a "
                                     "stored point's record cannot be replaced");
    }
  }
  // As a transform's: durable before the commit's log record, removed if it is not logged.
  const uint64_t first = next_id_.fetch_add(points.size());
  HVDB_RETURN_IF_ERROR(gaussians_->Write(first, records));
  segments->push_back(first);
  return first;
}

Status DatasetImpl::TurnGaussians(const std::array<double, 9>& linear,
                                  std::span<const Point> selected, std::span<Point> moved,
                                  std::vector<uint64_t>* segments) {
  HVDB_ASSIGN_OR_RETURN(GaussianColumns cols, ReadGaussians(selected, nullptr));
  const GaussianRecordMap map(linear);
  for (size_t i = 0; i < selected.size(); ++i) {
    if (!map.Apply(cols.sh_degree, cols.record(i))) {
      return Status::InvalidArgument("transform: splat " + std::to_string(selected[i].id) +
                                     " of frame " + std::to_string(selected[i].frame) +
                                     " would get a scale or colour beyond float");
    }
  }
  // Fresh ids, one run: the records are one segment, durable before the commit's log record
  // (a crash between leaves ids recovery finds unissued, and their segment is removed).
  const uint64_t first = next_id_.fetch_add(selected.size());
  HVDB_RETURN_IF_ERROR(gaussians_->Write(first, cols));
  segments->push_back(first);
  for (size_t i = 0; i < moved.size(); ++i) {
    moved[i].id = first + i;
    // The record's covariance, so that the point and its splat agree to the bit.
    moved[i].cov = GaussianCovariance(cols.record(i));
    moved[i].flags |= kFlagHasCovariance;
  }
  return Status::OK();
}

}  // namespace hvdb
