#include "storage/cold_tree.h"

#include <algorithm>
#include <bit>
#include <cstring>
#include <thread>

#include "blockcode/record_block.h"
#include "storage/coding.h"
#include "storage/crc32c.h"

namespace hvdb {
namespace {

// Points of the level segment stored in block `blk` (0: not a level-segment block).
uint32_t RecordsIn(const TreeHeader& h, uint32_t blk) {
  const uint32_t b = h.points_per_block;
  for (uint32_t k = 0; k < h.levels; ++k) {
    const uint32_t first = h.level_start_block[k];
    const uint32_t blocks = (h.level_count[k] + b - 1) / b;
    if (blk >= first && blk < first + blocks) {
      return std::min(b, h.level_count[k] - (blk - first) * b);
    }
  }
  return 0;
}

// Approximate bits of coding records[0, n) in this order: the magnitudes of the deltas of id and
// position (what the order changes most; record_block.cc codes every field by delta).
uint64_t OrderCost(const uint8_t* recs, const uint32_t* order, uint32_t n) {
  auto mono = [](uint32_t u) { return (u & 0x80000000u) ? ~u : (u | 0x80000000u); };
  auto bits = [](int64_t d) {
    return static_cast<uint64_t>(64 - std::countl_zero(static_cast<uint64_t>((d << 1) ^ (d >> 63))));
  };
  uint64_t cost = 0;
  for (uint32_t i = 1; i < n; ++i) {
    const uint8_t* a = recs + size_t{order[i]} * kPointRecordSize;
    const uint8_t* b = recs + size_t{order[i - 1]} * kPointRecordSize;
    cost += bits(static_cast<int64_t>(DecodeLE<uint64_t>(a) - DecodeLE<uint64_t>(b)));
    for (int c = 0; c < 3; ++c) {
      cost += bits(static_cast<int64_t>(mono(DecodeLE<uint32_t>(a + 8 + 4 * c))) -
                   static_cast<int64_t>(mono(DecodeLE<uint32_t>(b + 8 + 4 * c))));
    }
  }
  return cost;
}

// Within each bucket's points of each level, the order is free (a query returns them all or
// tests each): put them in id order where that codes smaller. Ids issued in capture order
// (pixel scan order, or a file's order) then cost ~5 bits a point instead of ~15, for about a
// bit more of position; where ids carry no locality the tree's spatial order stays.
void OrderForCoding(TreeImage* image) {
  const TreeHeader& h = image->header;
  const size_t bs = h.block_size;
  uint8_t* base = image->data.get();
  const uint32_t per = h.DirEntriesPerBlock();
  std::vector<uint32_t> kd, by_id;
  std::vector<uint8_t> tmp;
  for (uint32_t bucket = 0; bucket < h.bucket_count; ++bucket) {
    const DirEntry e = DecodeDirEntry(
        base + size_t{h.dir_block_start + bucket / per} * bs + size_t{bucket % per} * h.DirEntrySize(), h);
    for (uint32_t k = 0; k < h.levels; ++k) {
      const uint32_t n = e.count[k];
      if (n < 2) continue;
      uint8_t* recs = base + size_t{h.level_start_block[k]} * bs + size_t{e.start[k]} * kPointRecordSize;
      kd.resize(n);
      for (uint32_t i = 0; i < n; ++i) kd[i] = i;
      by_id = kd;
      std::sort(by_id.begin(), by_id.end(), [recs](uint32_t a, uint32_t b) {
        return DecodeLE<uint64_t>(recs + size_t{a} * kPointRecordSize) <
               DecodeLE<uint64_t>(recs + size_t{b} * kPointRecordSize);
      });
      if (OrderCost(recs, by_id.data(), n) >= OrderCost(recs, kd.data(), n)) continue;
      tmp.resize(size_t{n} * kPointRecordSize);
      for (uint32_t i = 0; i < n; ++i) {
        std::memcpy(tmp.data() + size_t{i} * kPointRecordSize,
                    recs + size_t{by_id[i]} * kPointRecordSize, kPointRecordSize);
      }
      std::memcpy(recs, tmp.data(), tmp.size());
    }
  }
}

std::string Trimmed(const uint8_t* block, uint32_t bs) {
  size_t used = bs;
  while (used > 0 && block[used - 1] == 0) --used;
  std::string out(1, static_cast<char>(ColdCoding::kTrimmed));
  out.append(reinterpret_cast<const char*>(block), used);
  return out;
}

}  // namespace

Status WriteCompressedTree(Env* env, const std::string& path, TreeImage& image, bool sync) {
  OrderForCoding(&image);
  TreeHeader h = image.header;
  const uint32_t bs = h.block_size;
  const uint8_t* base = image.data.get();
  const uint32_t data_end = h.crc_block_start;  // the checksum table's blocks are not stored
  std::vector<std::string> payload(h.total_blocks);
  std::vector<uint32_t> block_crc(h.total_blocks, 0);
  // Blocks are coded independently: two threads (the machine's cores), interleaved.
  auto code = [&](uint32_t first) {
    std::vector<uint8_t> check(bs);
    std::string err;
    for (uint32_t blk = first; blk < data_end; blk += 2) {
      if (blk == 0) continue;
      const uint8_t* src = base + size_t{blk} * bs;
      block_crc[blk] = crc32c::Mask(crc32c::Value(src, bs));
      const uint32_t n = RecordsIn(h, blk);
      if (n > 0) {
        std::string p(1, static_cast<char>(ColdCoding::kRecords));
        blockcode::EncodeRecordBlock(src, n, &p);
        // Decoded back before it is trusted: a record the coder cannot reproduce bit for bit
        // (nonzero reserved bytes), or noise that codes to more than a block, keeps its
        // block stored as it is.
        uint32_t got = 0;
        std::memset(check.data(), 0, bs);
        if (blockcode::DecodeRecordBlock(reinterpret_cast<const uint8_t*>(p.data()) + 1,
                                         p.size() - 1, check.data(), h.points_per_block, &got,
                                         &err) &&
            got == n && std::memcmp(check.data(), src, bs) == 0 && p.size() < bs) {
          payload[blk] = std::move(p);
          continue;
        }
      }
      payload[blk] = Trimmed(src, bs);
    }
  };
  std::thread other(code, 1u);
  code(0);
  other.join();

  h.version = h.label_summaries() ? kTreeVersionCompressed : kTreeVersionCompressedNoLabels;
  const uint64_t data_start = kTreeHeaderSize + kColdTableEntrySize * uint64_t{h.total_blocks};
  std::string table(kColdTableEntrySize * size_t{h.total_blocks}, '\0');
  uint64_t at = data_start;
  for (uint32_t blk = 0; blk < h.total_blocks; ++blk) {
    at += payload[blk].size();
    auto* e = reinterpret_cast<uint8_t*>(table.data()) + kColdTableEntrySize * blk;
    EncodeLE(e, at);
    EncodeLE(e + 8, payload[blk].empty() ? 0u
                                         : crc32c::Mask(crc32c::Value(payload[blk].data(),
                                                                      payload[blk].size())));
    EncodeLE(e + 12, block_crc[blk]);
  }
  h.crc_table_crc = crc32c::Mask(crc32c::Value(table.data(), table.size()));
  std::string file(kTreeHeaderSize, '\0');
  EncodeTreeHeader(h, reinterpret_cast<uint8_t*>(file.data()));
  file.reserve(at);
  file += table;
  for (const std::string& p : payload) file += p;
  return env->WriteNewFile(path, file, sync);
}

Result<ColdBlockTable> ReadColdBlockTable(RandomAccessFile* file, const TreeHeader& h,
                                          std::vector<uint32_t>* block_crcs) {
  const std::string& what = file->path();
  ColdBlockTable t;
  t.data_start = kTreeHeaderSize + kColdTableEntrySize * uint64_t{h.total_blocks};
  if (file->size() < t.data_start) {
    return Status::Corruption(what + ": truncated: " + std::to_string(file->size()) +
                              " bytes, smaller than its block table");
  }
  std::string table(kColdTableEntrySize * size_t{h.total_blocks}, '\0');
  HVDB_RETURN_IF_ERROR(file->Read(kTreeHeaderSize, table.size(), table.data()));
  if (crc32c::Unmask(h.crc_table_crc) != crc32c::Value(table.data(), table.size())) {
    return Status::Corruption(what + ": block table: checksum mismatch");
  }
  t.end.resize(h.total_blocks);
  t.payload_crc.resize(h.total_blocks);
  block_crcs->assign(h.total_blocks, 0);
  uint64_t prev = t.data_start;
  for (uint32_t blk = 0; blk < h.total_blocks; ++blk) {
    const auto* e = reinterpret_cast<const uint8_t*>(table.data()) + kColdTableEntrySize * blk;
    t.end[blk] = DecodeLE<uint64_t>(e);
    t.payload_crc[blk] = DecodeLE<uint32_t>(e + 8);
    (*block_crcs)[blk] = DecodeLE<uint32_t>(e + 12);
    // A payload is at most a trimmed block plus its coding byte, or a record block (which
    // codes 64-byte records in fewer bytes except for pathological data: bounded at 2 B).
    if (t.end[blk] < prev || t.end[blk] - prev > 2ull * h.block_size + 64) {
      return Status::Corruption(what + ": block table: block " + std::to_string(blk) +
                                " has a bad extent");
    }
    prev = t.end[blk];
  }
  if (prev != file->size()) {
    return Status::Corruption(what + ": truncated or overlong: " + std::to_string(file->size()) +
                              " bytes, block table says " + std::to_string(prev));
  }
  return t;
}

Status DecodeColdBlock(const TreeHeader& h, uint32_t blk, const uint8_t* payload, size_t len,
                       uint32_t payload_crc, uint32_t block_crc, uint8_t* dst,
                       const std::string& what) {
  const uint32_t bs = h.block_size;
  auto corrupt = [&](const std::string& m) {
    return Status::Corruption(what + ": block " + std::to_string(blk) + ": " + m);
  };
  if (len == 0) return corrupt("no payload stored for a data block");
  if (crc32c::Unmask(payload_crc) != crc32c::Value(payload, len)) {
    return corrupt("checksum mismatch (compressed payload)");
  }
  const auto coding = static_cast<ColdCoding>(payload[0]);
  if (coding == ColdCoding::kTrimmed) {
    if (len - 1 > bs) return corrupt("stored block longer than a block");
    std::memcpy(dst, payload + 1, len - 1);
    std::memset(dst + (len - 1), 0, bs - (len - 1));
  } else if (coding == ColdCoding::kRecords) {
    const uint32_t want = RecordsIn(h, blk);
    uint32_t got = 0;
    std::string err;
    if (want == 0) return corrupt("record coding outside the level segments");
    if (!blockcode::DecodeRecordBlock(payload + 1, len - 1, dst, h.points_per_block, &got, &err)) {
      return corrupt("record block: " + err);
    }
    if (got != want) {
      return corrupt("record block holds " + std::to_string(got) + " points, the tree " +
                     std::to_string(want));
    }
    std::memset(dst + size_t{got} * kPointRecordSize, 0, bs - size_t{got} * kPointRecordSize);
  } else {
    return corrupt("unknown block coding " + std::to_string(payload[0]));
  }
  if (crc32c::Unmask(block_crc) != crc32c::Value(dst, bs)) {
    return corrupt("checksum mismatch (decoded block)");
  }
  return Status::OK();
}

}  // namespace hvdb
