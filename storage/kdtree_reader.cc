#include "storage/kdtree_reader.h"

#include <algorithm>
#include <cstdlib>
#include <cstring>

#include "storage/coding.h"
#include "storage/crc32c.h"

namespace hvdb {

Result<std::shared_ptr<KdTree>> KdTree::Open(Env* env, const std::string& path,
                                             BufferPool* pool, bool synced) {
  HVDB_ASSIGN_OR_RETURN(auto file, env->OpenRead(path));
  uint8_t head[kTreeHeaderSize];
  if (file->size() < kTreeHeaderSize) {
    return Status::Corruption(path + ": truncated: " + std::to_string(file->size()) +
                              " bytes, smaller than a header");
  }
  HVDB_RETURN_IF_ERROR(file->Read(0, kTreeHeaderSize, head));
  HVDB_ASSIGN_OR_RETURN(TreeHeader h, DecodeTreeHeader(head, path));
  if (h.block_size != pool->block_size()) {
    return Status::InvalidArgument(path + ": block size " + std::to_string(h.block_size) +
                                   " differs from the database's " +
                                   std::to_string(pool->block_size()));
  }
  if (h.compressed()) {
    std::vector<uint32_t> crcs;
    HVDB_ASSIGN_OR_RETURN(ColdBlockTable cold, ReadColdBlockTable(file.get(), h, &crcs));
    auto tree = std::shared_ptr<KdTree>(
        new KdTree(env, std::move(file), pool, h, std::move(crcs),
                   std::make_shared<const ColdBlockTable>(std::move(cold))));
    tree->synced_ = synced;
    return tree;
  }
  if (file->size() != uint64_t{h.total_blocks} * h.block_size) {
    return Status::Corruption(path + ": truncated: " + std::to_string(file->size()) +
                              " bytes, header says " +
                              std::to_string(uint64_t{h.total_blocks} * h.block_size));
  }
  std::string table(size_t{h.crc_block_count} * h.block_size, '\0');
  HVDB_RETURN_IF_ERROR(file->Read(uint64_t{h.crc_block_start} * h.block_size, table.size(),
                                  table.data()));
  if (crc32c::Unmask(h.crc_table_crc) != crc32c::Value(table.data(), table.size())) {
    return Status::Corruption(path + ": blocks " + std::to_string(h.crc_block_start) + ".." +
                              std::to_string(h.total_blocks - 1) +
                              " (checksum table): checksum mismatch");
  }
  std::vector<uint32_t> crcs(h.total_blocks);
  for (uint32_t i = 0; i < h.total_blocks; ++i) {
    crcs[i] = DecodeLE<uint32_t>(reinterpret_cast<const uint8_t*>(table.data()) + 4 * size_t{i});
  }
  auto tree = std::shared_ptr<KdTree>(
      new KdTree(env, std::move(file), pool, h, std::move(crcs), nullptr));
  tree->synced_ = synced;
  return tree;
}

KdTree::KdTree(Env* env, std::shared_ptr<RandomAccessFile> file, BufferPool* pool, TreeHeader h,
               std::vector<uint32_t> crcs, std::shared_ptr<const ColdBlockTable> cold)
    : env_(env), file_(std::move(file)), pool_(pool), h_(h),
      crcs_(std::make_shared<const std::vector<uint32_t>>(std::move(crcs))),
      cold_(std::move(cold)), file_id_(pool->NewFileId()) {}

KdTree::~KdTree() {
  pool_->Forget(file_id_);
  if (obsolete_) (void)env_->Remove(file_->path());
}

Status KdTree::Sync() {
  if (synced_.load()) return Status::OK();
  HVDB_ASSIGN_OR_RETURN(auto f, env_->OpenWrite(file_->path(), /*truncate=*/false));
  HVDB_RETURN_IF_ERROR(f->Sync());
  synced_ = true;
  return Status::OK();
}

Status KdTree::LoadBlock(uint32_t blk, uint8_t* dst) const {
  if (blk == 0 || blk >= h_.crc_block_start) {
    return Status::Corruption(path() + ": reference to block " + std::to_string(blk) +
                              " outside the data blocks");
  }
  if (cold_) {
    const uint64_t at = cold_->Start(blk);
    std::vector<uint8_t> payload(cold_->end[blk] - at);
    HVDB_RETURN_IF_ERROR(file_->Read(at, payload.size(), payload.data()));
    return DecodeColdBlock(h_, blk, payload.data(), payload.size(), cold_->payload_crc[blk],
                           (*crcs_)[blk], dst, path());
  }
  HVDB_RETURN_IF_ERROR(file_->Read(uint64_t{blk} * h_.block_size, h_.block_size, dst));
  if (crc32c::Unmask((*crcs_)[blk]) != crc32c::Value(dst, h_.block_size)) {
    return Status::Corruption(path() + ": block " + std::to_string(blk) +
                              ": checksum mismatch");
  }
  return Status::OK();
}

Result<PageRef> KdTree::Block(uint32_t blk) const {
  return pool_->Fetch(file_id_, blk, [this, blk](uint8_t* dst) { return LoadBlock(blk, dst); });
}

Result<DirEntry> KdTree::Dir(uint32_t bucket) const {
  if (bucket >= h_.bucket_count) {
    return Status::Corruption(path() + ": bucket " + std::to_string(bucket) + " out of range");
  }
  uint32_t per = h_.DirEntriesPerBlock();
  HVDB_ASSIGN_OR_RETURN(PageRef page, Block(h_.dir_block_start + bucket / per));
  return DecodeDirEntry(page.data() + size_t{bucket % per} * h_.DirEntrySize(), h_);
}

void KdTree::PrefetchBlocks(const std::vector<uint32_t>& blocks) const {
  if (blocks.empty()) return;
  // Batches of up to 512 KiB: the query starts on the first while the next are in flight (on
  // the test machine, 1-8 MiB batches made a cold full frame slower, 256 KiB no faster:
  // bench/README.md).
  const size_t batch = std::max<size_t>(1, (512u << 10) / h_.block_size);
  const uint32_t bs = h_.block_size, data_end = h_.crc_block_start;
  if (cold_) {
    PrefetchColdBlocks(blocks, batch);
    return;
  }
  pool_->Prefetch(file_id_, blocks, batch,
                  [file = file_, crcs = crcs_, bs, data_end](std::span<BufferPool::BlockLoad> loads) {
    // Adjacent blocks become one request (up to 1 MiB), scattered into their pool slots;
    // every request of the batch is issued at once. Checksums are verified here, on the
    // loader thread, while the query consumes earlier blocks.
    std::vector<ReadRequest> reqs;
    std::vector<std::pair<size_t, size_t>> span_of;  // loads [first, last) of each request
    const size_t max_run = std::max<size_t>(1, (1u << 20) / bs);
    for (size_t i = 0; i < loads.size();) {
      size_t j = i + 1;
      while (j < loads.size() && j - i < max_run && loads[j].block == loads[j - 1].block + 1) ++j;
      ReadRequest r;
      r.offset = uint64_t{loads[i].block} * bs;
      for (size_t k = i; k < j; ++k) r.buffers.push_back({loads[k].dst, bs});
      reqs.push_back(std::move(r));
      span_of.push_back({i, j});
      i = j;
    }
    file->ReadBatch(reqs);
    for (size_t r = 0; r < reqs.size(); ++r) {
      for (size_t k = span_of[r].first; k < span_of[r].second; ++k) {
        const uint32_t blk = loads[k].block;
        loads[k].ok = reqs[r].status.ok() && blk != 0 && blk < data_end &&
                      crc32c::Unmask((*crcs)[blk]) == crc32c::Value(loads[k].dst, bs);
      }
    }
  });
}

void KdTree::PrefetchColdBlocks(const std::vector<uint32_t>& blocks, size_t batch) const {
  pool_->Prefetch(file_id_, blocks, batch,
                  [file = file_, crcs = crcs_, cold = cold_, h = h_](
                      std::span<BufferPool::BlockLoad> loads) {
    // Adjacent blocks' payloads are adjacent in the file: one request per run, then each
    // payload decoded into its pool slot here, on the loader thread (the pool's loaders decode
    // a frame's blocks in parallel while the query consumes earlier ones).
    std::vector<std::string> bufs;
    std::vector<ReadRequest> reqs;
    std::vector<std::pair<size_t, size_t>> span_of;
    for (size_t i = 0; i < loads.size();) {
      size_t j = i + 1;
      while (j < loads.size() && j - i < 64 && loads[j].block == loads[j - 1].block + 1) ++j;
      span_of.push_back({i, j});
      i = j;
    }
    bufs.resize(span_of.size());
    for (size_t r = 0; r < span_of.size(); ++r) {
      const uint32_t first = loads[span_of[r].first].block;
      const uint32_t last = loads[span_of[r].second - 1].block;
      bool in_range = first != 0 && last < h.crc_block_start;
      uint64_t at = in_range ? cold->Start(first) : 0;
      bufs[r].resize(in_range ? cold->end[last] - at : 0);
      ReadRequest q;
      q.offset = at;
      q.buffers.push_back({reinterpret_cast<uint8_t*>(bufs[r].data()), bufs[r].size()});
      if (!bufs[r].empty()) reqs.push_back(std::move(q));
    }
    file->ReadBatch(reqs);
    for (size_t r = 0, q = 0; r < span_of.size(); ++r) {
      if (bufs[r].empty()) continue;  // not ok: Fetch loads the blocks and reports the error
      const ReadRequest& req = reqs[q++];
      const uint64_t base = req.offset;
      for (size_t k = span_of[r].first; k < span_of[r].second; ++k) {
        const uint32_t blk = loads[k].block;
        if (!req.status.ok()) continue;
        const uint64_t at = cold->Start(blk) - base;
        loads[k].ok =
            DecodeColdBlock(h, blk, reinterpret_cast<const uint8_t*>(bufs[r].data()) + at,
                            cold->end[blk] - cold->Start(blk), cold->payload_crc[blk],
                            (*crcs)[blk], loads[k].dst, file->path())
                .ok();
      }
    }
  });
}

void KdTree::Prefetch(const std::vector<BucketHit>& hits, int lo, int hi) const {
  const uint32_t b = h_.points_per_block;
  std::vector<uint32_t> blocks;
  // Coarse levels first: their segments come first in the file (fig. 8.11).
  for (int k = std::min<int>(hi, static_cast<int>(h_.levels) - 1); k >= std::max(lo, 0); --k) {
    for (const BucketHit& hit : hits) {
      const uint32_t n = hit.entry.count[k];
      if (n == 0) continue;
      const uint32_t s = hit.entry.start[k];
      for (uint32_t blk = s / b; blk <= (s + n - 1) / b; ++blk) {
        if (blocks.empty() || blocks.back() != h_.level_start_block[k] + blk) {
          blocks.push_back(h_.level_start_block[k] + blk);
        }
      }
    }
  }
  std::sort(blocks.begin(), blocks.end());
  PrefetchBlocks(blocks);
}

Status KdTree::FindBuckets(const BoxTest& test, std::vector<BucketHit>* out,
                           uint32_t label_mask) const {
  if (test(h_.bbox) == Relation::kOutside) return Status::OK();
  if (label_mask != 0 && (h_.labels & label_mask) == 0) return Status::OK();
  {
    // The walk reads node blocks, then directory blocks, one after another: ask for all of
    // them at once (they are contiguous, and few) unless they are cached.
    std::vector<uint32_t> meta;
    for (uint32_t blk = h_.node_block_start; blk < h_.crc_block_start; ++blk) meta.push_back(blk);
    PrefetchBlocks(meta);
  }
  auto visit_bucket = [&](uint32_t bucket) -> Status {
    HVDB_ASSIGN_OR_RETURN(DirEntry e, Dir(bucket));
    if (label_mask != 0 && (e.labels & label_mask) == 0) return Status::OK();
    Relation r = test(e.box);
    if (r != Relation::kOutside) out->push_back({bucket, r == Relation::kInside, e});
    return Status::OK();
  };
  if (h_.root_type == ChildType::kBucket) return visit_bucket(h_.root_ref);
  // Iterative DFS over (node block, node index) with the node's box, left before right.
  struct Item {
    uint32_t block, node;
    Box3 box;
  };
  std::vector<Item> stack{{h_.root_ref, 0, h_.bbox}};
  const uint32_t max_nodes = h_.NodesPerBlock();
  while (!stack.empty()) {
    Item it = stack.back();
    stack.pop_back();
    if (it.block == UINT32_MAX) {  // a bucket, in storage order
      HVDB_RETURN_IF_ERROR(visit_bucket(it.node));
      continue;
    }
    if (it.block >= h_.node_block_count) {
      return Status::Corruption(path() + ": node block " + std::to_string(it.block) +
                                " out of range");
    }
    HVDB_ASSIGN_OR_RETURN(PageRef page, Block(h_.node_block_start + it.block));
    uint32_t count = DecodeLE<uint32_t>(page.data());
    if (count > max_nodes || it.node >= count) {
      return Status::Corruption(path() + ": block " +
                                std::to_string(h_.node_block_start + it.block) +
                                ": bad node index");
    }
    NodeRecord n = DecodeNode(page.data() + kNodeBlockHeader + size_t{it.node} * kNodeRecordSize);
    page.Release();
    if (n.axis > 2) return Status::Corruption(path() + ": node with axis > 2");
    Box3 lbox = it.box, rbox = it.box;
    lbox.hi[n.axis] = std::min(lbox.hi[n.axis], n.split);
    rbox.lo[n.axis] = std::max(rbox.lo[n.axis], n.split);
    // Push right first so left is visited first (storage order).
    std::pair<ChildType, uint32_t> kids[2] = {{n.right_type, n.right}, {n.left_type, n.left}};
    const Box3* boxes[2] = {&rbox, &lbox};
    // Buckets are pushed as pseudo-items (block UINT32_MAX) to keep depth-first order.
    for (int s = 0; s < 2; ++s) {
      auto [type, ref] = kids[s];
      if (test(*boxes[s]) == Relation::kOutside) continue;
      switch (type) {
        case ChildType::kNode: stack.push_back({it.block, ref, *boxes[s]}); break;
        case ChildType::kNodeBlock: stack.push_back({ref, 0, *boxes[s]}); break;
        case ChildType::kBucket:
          stack.push_back({UINT32_MAX, ref, *boxes[s]});
          break;
        default: return Status::Corruption(path() + ": bad child type");
      }
    }
  }
  return Status::OK();
}

Status KdTree::ReadRange(int level, uint32_t start, uint32_t count,
                         const std::function<void(const uint8_t*, size_t)>& fn) const {
  const uint32_t b = h_.points_per_block;
  if (level < 0 || static_cast<uint32_t>(level) >= h_.levels ||
      uint64_t{start} + count > h_.level_count[level]) {
    return Status::Corruption(path() + ": level range out of bounds");
  }
  while (count > 0) {
    uint32_t blk = h_.level_start_block[level] + start / b;
    uint32_t off = start % b;
    uint32_t n = std::min(count, b - off);
    HVDB_ASSIGN_OR_RETURN(PageRef page, Block(blk));
    fn(page.data() + size_t{off} * kPointRecordSize, n);
    start += n;
    count -= n;
  }
  return Status::OK();
}

Status KdTree::ReadAll(std::vector<Point>* out) const {
  size_t base = out->size();
  out->resize(base + h_.point_count);
  Point* dst = out->data() + base;
  for (uint32_t k = 0; k < h_.levels; ++k) {
    HVDB_RETURN_IF_ERROR(ReadRange(static_cast<int>(k), 0, h_.level_count[k],
                                   [&dst](const uint8_t* rec, size_t n) {
                                     DecodePoints(rec, n, dst);
                                     dst += n;
                                   }));
  }
  return Status::OK();
}

Status KdTree::ReadImage(TreeImage* out) const {
  const size_t bs = h_.block_size;
  out->bytes = size_t{h_.total_blocks} * bs;
  out->data.reset(static_cast<uint8_t*>(std::aligned_alloc(4096, (out->bytes + 4095) / 4096 * 4096)));
  if (!out->data) return Status::IOError("out of memory for a " + std::to_string(out->bytes) + "-byte tree");
  uint8_t* base = out->data.get();
  if (!cold_) HVDB_RETURN_IF_ERROR(file_->Read(0, out->bytes, base));
  std::memset(base, 0, bs);
  for (uint32_t blk = 1; blk < h_.crc_block_start; ++blk) {
    if (cold_) {
      HVDB_RETURN_IF_ERROR(LoadBlock(blk, base + blk * bs));
    } else if (crc32c::Unmask((*crcs_)[blk]) != crc32c::Value(base + blk * bs, bs)) {
      return Status::Corruption(path() + ": block " + std::to_string(blk) + ": checksum mismatch");
    }
  }
  // The raw format's checksum table and header.
  uint8_t* table = base + size_t{h_.crc_block_start} * bs;
  std::memset(table, 0, size_t{h_.crc_block_count} * bs);
  for (uint32_t blk = 1; blk < h_.crc_block_start; ++blk) EncodeLE(table + 4 * blk, (*crcs_)[blk]);
  out->header = h_;
  out->header.version = h_.label_summaries() ? kTreeVersion : kTreeVersionNoLabels;
  out->header.crc_table_crc = crc32c::Mask(crc32c::Value(table, size_t{h_.crc_block_count} * bs));
  EncodeTreeHeader(out->header, base);
  return Status::OK();
}

std::vector<std::string> KdTree::Verify() const {
  std::vector<std::string> problems;
  const uint32_t bs = h_.block_size;
  std::vector<uint8_t> buf(bs);
  bool blocks_ok = true;
  for (uint32_t blk = 1; blk < h_.crc_block_start; ++blk) {
    Status s = LoadBlock(blk, buf.data());
    if (!s.ok()) {
      problems.push_back(s.ToString());
      blocks_ok = false;
    }
  }
  if (!blocks_ok) return problems;  // structure checks would only repeat the same failures
  // Read the directory and all points straight from the file.
  auto read_entry = [&](uint32_t bucket) {
    uint32_t per = h_.DirEntriesPerBlock();
    std::vector<uint8_t> blk(bs);
    (void)LoadBlock(h_.dir_block_start + bucket / per, blk.data());  // checked above
    return DecodeDirEntry(blk.data() + size_t{bucket % per} * h_.DirEntrySize(), h_);
  };
  const uint64_t cap = 2ull * h_.points_per_block;
  uint64_t total = 0;
  for (uint32_t i = 0; i < h_.bucket_count; ++i) {
    DirEntry e = read_entry(i);
    uint64_t n = 0;
    if ((e.labels & ~h_.labels) != 0) {
      problems.push_back(path() + ": bucket " + std::to_string(i) +
                         ": label summary has bits the header's lacks");
    }
    for (uint32_t k = 0; k < h_.levels; ++k) {
      n += e.count[k];
      Status s = ReadRange(static_cast<int>(k), e.start[k], e.count[k],
                           [&](const uint8_t* rec, size_t cnt) {
                             for (size_t j = 0; j < cnt; ++j) {
                               Point p = DecodePoint(rec + j * kPointRecordSize);
                               float c[3] = {p.x, p.y, p.z};
                               for (int a = 0; a < 3; ++a) {
                                 if (c[a] < e.box.lo[a] || c[a] > e.box.hi[a]) {
                                   problems.push_back(path() + ": bucket " + std::to_string(i) +
                                                      ": point " + std::to_string(p.id) +
                                                      " outside the bucket box");
                                   return;
                                 }
                               }
                               if ((p.label & ~e.labels) != 0) {
                                 problems.push_back(path() + ": bucket " + std::to_string(i) +
                                                    ": point " + std::to_string(p.id) +
                                                    " has label bits its summary lacks");
                                 return;
                               }
                               if (p.frame != h_.frame) {
                                 problems.push_back(path() + ": point " + std::to_string(p.id) +
                                                    " has frame " + std::to_string(p.frame) +
                                                    ", tree holds frame " +
                                                    std::to_string(h_.frame));
                                 return;
                               }
                             }
                           });
      if (!s.ok()) problems.push_back(s.ToString());
    }
    if (n > cap) problems.push_back(path() + ": bucket " + std::to_string(i) + " overfull");
    if (n < cap && i + 1 != h_.bucket_count) {
      problems.push_back(path() + ": bucket " + std::to_string(i) +
                         " not full but not the last one (utilisation invariant)");
    }
    total += n;
  }
  if (total != h_.point_count) problems.push_back(path() + ": bucket sizes != point count");
  // Every node's split must separate its children's bucket boxes.
  BoxTest everything = [](const Box3&) { return Relation::kCrosses; };
  std::vector<BucketHit> hits;
  Status s = FindBuckets(everything, &hits);
  if (!s.ok()) problems.push_back(s.ToString());
  if (s.ok() && hits.size() != h_.bucket_count) {
    problems.push_back(path() + ": the node tree reaches " + std::to_string(hits.size()) +
                       " of " + std::to_string(h_.bucket_count) + " buckets");
  }
  for (size_t i = 0; i < hits.size(); ++i) {
    if (hits[i].bucket != i) {
      problems.push_back(path() + ": buckets out of depth-first order");
      break;
    }
  }
  return problems;
}

}  // namespace hvdb
