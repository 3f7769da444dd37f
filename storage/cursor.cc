// CursorImpl: a query's state machine over (level, frame, tree, bucket), holding its snapshot.
#include <cmath>
#include <cstring>

#include "storage/dataset_impl.h"
#include "storage/coding.h"
#include "storage/lod.h"

namespace hvdb {

class CursorImpl {
 public:
  CursorImpl(RegionPlan plan, const QueryOptions& opts, int max_level)
      : plan_(std::move(plan)), versions_(std::move(plan_.versions)), opts_(opts),
        max_level_(max_level) {
    // Temporal LOD (8.4) applies when the plan skipped frames for it.
    temporal_stride_ = 1;
    if (opts.temporal_lod && opts.lod > 0 && plan_.frames.size() > 1) temporal_stride_ = 1 << opts.lod;
    auto add_frame_tasks = [&](uint32_t fi, int level) {
      const FrameVersion& v = *versions_[fi];
      for (size_t s = 0; s < v.slots.size(); ++s) {
        if (v.slots[s].tree) tasks_.push_back({fi, static_cast<int>(s), level});
      }
      tasks_.push_back({fi, -1, level});
    };
    const auto nf = static_cast<uint32_t>(versions_.size());
    if (opts.progressive) {
      for (int k = max_level; k >= opts.lod; --k) {
        for (uint32_t fi = 0; fi < nf; ++fi) add_frame_tasks(fi, k);
      }
    } else {
      for (uint32_t fi = 0; fi < nf; ++fi) {
        const FrameVersion& v = *versions_[fi];
        for (size_t s = 0; s < v.slots.size(); ++s) {
          if (!v.slots[s].tree) continue;
          for (int k = max_level; k >= opts.lod; --k) tasks_.push_back({fi, static_cast<int>(s), k});
        }
        for (int k = max_level; k >= opts.lod; --k) tasks_.push_back({fi, -1, k});
      }
    }
  }

  // Fills batch->points, or, when `buf` is set, buf[0..cap) (batch->points untouched; the
  // count goes to *n): the server's shared-memory ring is filled straight from the blocks.
  Result<bool> Next(Batch* batch, Point* buf = nullptr, size_t cap = 0, size_t* n = nullptr) {
    out_ = Out{buf ? nullptr : &batch->points, buf, 0, cap};
    if (buf && n) *n = 0;
    Result<bool> r = NextBatch(batch);
    if (buf && n) *n = out_.n;
    return r;
  }

  Result<bool> NextBatch(Batch* batch) {
    if (out_.vec) out_.vec->clear();
    batch->level_done = false;
    if (cancelled_.load(std::memory_order_relaxed)) return Status::Cancelled("query cancelled");
    if (task_ >= tasks_.size()) return false;
    const int batch_level = opts_.progressive ? tasks_[task_].level : opts_.lod;
    batch->level = batch_level;
    batch->splat_scale = static_cast<float>(std::pow(2.0, batch_level / 2.0));
    while (task_ < tasks_.size()) {
      const Task& t = tasks_[task_];
      if (opts_.progressive && t.level != batch_level) {
        batch->level_done = true;
        return true;
      }
      if (cancelled_.load(std::memory_order_relaxed)) return Status::Cancelled("query cancelled");
      HVDB_ASSIGN_OR_RETURN(bool finished, RunTask(t));
      if (!finished) return true;  // batch full; resume this task next time
      ++task_;
      bucket_pos_ = 0;
    }
    if (opts_.progressive) batch->level_done = true;
    return true;
  }

  void Cancel() { cancelled_ = true; }
  const std::vector<uint32_t>& frames() const { return plan_.frames; }
  bool clipped() const { return plan_.clipped; }
  uint64_t PointsBound() const {
    uint64_t n = 0;
    for (const auto& v : versions_) {
      n += v->t0.size();
      for (const TreeSlot& s : v->slots) n += s.live();
    }
    return n;
  }

 private:
  struct Task {
    uint32_t frame_idx;
    int slot;  // -1: the buffer T0
    int level;
  };

  // Where a batch's points go: a vector, or a caller's buffer of fixed capacity.
  struct Out {
    std::vector<Point>* vec = nullptr;
    Point* buf = nullptr;
    size_t n = 0, cap = 0;
    size_t size() const { return vec ? vec->size() : n; }
    bool Room(size_t k) const { return vec || n + k <= cap; }
    Point* Grow(size_t k) {
      if (vec) {
        size_t at = vec->size();
        vec->resize(at + k);
        return vec->data() + at;
      }
      Point* p = buf + n;
      n += k;
      return p;
    }
  };

  void Emit(Point p, const FrameVersion& v) {
    if (plan_.slice) {
      double t = plan_.FrameTime(v.frame);
      plan_.slice->Project(&p, t, temporal_stride_ / plan_.fps);
    }
    if (out_.vec) {
      out_.vec->push_back(p);
    } else {
      out_.buf[out_.n++] = p;
    }
  }

  bool Accept(const Point& p, bool inside) const {
    if (opts_.label_mask != 0 && (p.label & opts_.label_mask) == 0) return false;
    return inside || plan_.Contains(p);
  }

  // Returns true when the task is done, false when the batch filled up first.
  Result<bool> RunTask(const Task& t) {
    const FrameVersion& v = *versions_[t.frame_idx];
    if (t.slot < 0) {
      // bucket_pos_ counts points of T0 across its chunks.
      size_t base = 0;
      for (const auto& chunk : v.t0.chunks()) {
        const size_t n = chunk->size();
        if (bucket_pos_ >= base + n) {
          base += n;
          continue;
        }
        for (size_t j = bucket_pos_ - base; j < n; ++j, ++bucket_pos_) {
          const Point& p = (*chunk)[j];
          if (LevelOfId(p.id, max_level()) != t.level || !Accept(p, false)) continue;
          // A full buffer, or a full batch: resume at this point.
          if (!out_.Room(1) || out_.size() >= opts_.batch_points) return false;
          Emit(p, v);
        }
        base += n;
      }
      return true;
    }
    const TreeSlot& slot = v.slots[static_cast<size_t>(t.slot)];
    auto key = std::make_pair(t.frame_idx, t.slot);
    auto it = buckets_.find(key);
    if (it == buckets_.end()) {
      std::vector<KdTree::BucketHit> hits;
      const uint32_t frame = v.frame;
      HVDB_RETURN_IF_ERROR(slot.tree->FindBuckets(
          [&](const Box3& b) { return plan_.Classify(b, frame); }, &hits, opts_.label_mask));
      // Every block this task and the slot's later levels will read, requested at once; a
      // progressive query asks for this level and the next finer one (read while the caller
      // consumes this one), and for each further level when it starts.
      slot.tree->Prefetch(hits, opts_.progressive ? std::max(opts_.lod, t.level - 1) : opts_.lod,
                          t.level);
      it = buckets_.emplace(key, std::move(hits)).first;
    } else if (opts_.progressive && bucket_pos_ == 0 && t.level - 1 >= opts_.lod) {
      slot.tree->Prefetch(it->second, t.level - 1, t.level - 1);
    }
    const auto& hits = it->second;
    const size_t limit = opts_.batch_points;
    for (; bucket_pos_ < hits.size(); ++bucket_pos_) {
      const auto& hit = hits[bucket_pos_];
      const auto k = static_cast<size_t>(t.level);
      if (out_.size() >= limit || (!out_.Room(hit.entry.count[k]) && out_.size() > 0)) return false;
      if (!out_.Room(hit.entry.count[k])) {
        return Status::InvalidArgument("query buffer of " + std::to_string(out_.cap) +
                                       " points cannot hold one bucket level of " +
                                       std::to_string(hit.entry.count[k]));
      }
      if (hit.inside && !slot.dead && opts_.label_mask == 0 && !plan_.slice) {
        // Every record is a result as stored: copy runs of records, no per-point work.
        HVDB_RETURN_IF_ERROR(slot.tree->ReadRange(
            t.level, hit.entry.start[k], hit.entry.count[k], [&](const uint8_t* rec, size_t n) {
              DecodePoints(rec, n, out_.Grow(n));
            }));
        continue;
      }
      if (plan_.window && opts_.label_mask == 0) {
        // A window crossing the bucket: test the stored coordinates in place (offsets 8, 12,
        // 16 of a record) and copy out only the hits, instead of decoding every record.
        const Window& w = *plan_.window;
        HVDB_RETURN_IF_ERROR(slot.tree->ReadRange(
            t.level, hit.entry.start[k], hit.entry.count[k], [&](const uint8_t* rec, size_t n) {
              for (size_t j = 0; j < n; ++j) {
                const uint8_t* r = rec + j * kPointRecordSize;
                float c[3];
                std::memcpy(c, r + 8, sizeof c);
                if (!(c[0] >= w.lo[0] && c[0] <= w.hi[0] && c[1] >= w.lo[1] && c[1] <= w.hi[1] &&
                      c[2] >= w.lo[2] && c[2] <= w.hi[2])) {
                  continue;
                }
                if (slot.dead && slot.IsDead(DecodeLE<uint64_t>(r))) continue;
                DecodePoints(r, 1, out_.Grow(1));
              }
            }));
        continue;
      }
      HVDB_RETURN_IF_ERROR(slot.tree->ReadRange(
          t.level, hit.entry.start[k], hit.entry.count[k], [&](const uint8_t* rec, size_t n) {
            for (size_t j = 0; j < n; ++j) {
              Point p = DecodePoint(rec + j * kPointRecordSize);
              if (slot.IsDead(p.id) || !Accept(p, hit.inside)) continue;
              Emit(p, v);
            }
          }));
    }
    // Bucket lists are kept for the finer levels of a progressive query.
    if (!opts_.progressive || t.level == opts_.lod) buckets_.erase(key);
    return true;
  }

  int max_level() const { return max_level_; }

  RegionPlan plan_;
  std::vector<std::shared_ptr<const FrameVersion>> versions_;
  QueryOptions opts_;
  int max_level_;
  int temporal_stride_ = 1;
  std::vector<Task> tasks_;
  size_t task_ = 0, bucket_pos_ = 0;
  std::map<std::pair<uint32_t, int>, std::vector<KdTree::BucketHit>> buckets_;
  std::atomic<bool> cancelled_{false};
  Out out_;
};

Result<std::unique_ptr<Cursor>> DatasetImpl::Query(const Region& region,
                                                   const QueryOptions& opts) {
  if (opts.batch_points == 0) return Status::InvalidArgument("batch_points must be > 0");
  HVDB_ASSIGN_OR_RETURN(RegionPlan plan, Plan(region, opts.lod, opts.temporal_lod));
  auto impl = std::make_unique<CursorImpl>(std::move(plan), opts, opts_.lod_levels);
  return std::make_unique<Cursor>(std::move(impl));
}

Cursor::Cursor(std::unique_ptr<CursorImpl> impl) : impl_(std::move(impl)) {}
Cursor::~Cursor() = default;
Result<bool> Cursor::Next(Batch* batch) { return impl_->Next(batch); }
Result<bool> Cursor::NextInto(Point* buf, size_t capacity, size_t* n, Batch* info) {
  if (buf == nullptr || capacity == 0) {
    return Status::InvalidArgument("Cursor::NextInto: needs a buffer");
  }
  return impl_->Next(info, buf, capacity, n);
}
void Cursor::Cancel() { impl_->Cancel(); }
const std::vector<uint32_t>& Cursor::frames() const { return impl_->frames(); }
bool Cursor::clipped() const { return impl_->clipped(); }
uint64_t Cursor::PointsBound() const { return impl_->PointsBound(); }

}  // namespace hvdb
