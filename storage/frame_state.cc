#include "storage/frame_state.h"

#include <algorithm>
#include <cinttypes>
#include <cstdio>
#include <cstring>
#include <limits>

#include "storage/coding.h"
#include "storage/crc32c.h"

namespace hvdb {

static constexpr char kFrameMagic[8] = {'H', 'V', 'D', 'B', 'F', 'S', 'T', '\0'};
static constexpr uint32_t kFrameVersion = 1;

std::vector<Point> PointBuffer::ToVector() const {
  std::vector<Point> out;
  out.reserve(size_);
  for (const Chunk& c : chunks_) out.insert(out.end(), c->begin(), c->end());
  return out;
}

void PointBuffer::Append(std::vector<Point> pts) {
  if (pts.empty()) return;
  size_ += pts.size();
  // Small commits extend a small last chunk (a bounded copy) instead of adding a chunk each.
  constexpr size_t kSmallChunk = 1024;
  if (!chunks_.empty() && chunks_.back()->size() < kSmallChunk) {
    auto merged = std::make_shared<std::vector<Point>>();
    merged->reserve(chunks_.back()->size() + pts.size());
    merged->insert(merged->end(), chunks_.back()->begin(), chunks_.back()->end());
    merged->insert(merged->end(), pts.begin(), pts.end());
    chunks_.back() = std::move(merged);
    return;
  }
  chunks_.push_back(std::make_shared<const std::vector<Point>>(std::move(pts)));
}

PointBuffer PointBuffer::Suffix(size_t n) const {
  PointBuffer out;
  for (const Chunk& c : chunks_) {
    if (n >= c->size()) {
      n -= c->size();
      continue;
    }
    if (n == 0) {
      out.chunks_.push_back(c);
    } else {
      out.chunks_.push_back(std::make_shared<const std::vector<Point>>(c->begin() + n, c->end()));
      n = 0;
    }
    out.size_ += out.chunks_.back()->size();
  }
  return out;
}

uint64_t FrameVersion::PointCount() const {
  uint64_t n = t0.size();
  for (const TreeSlot& s : slots) n += s.live();
  return n;
}

Box3 FrameVersion::Bounds() const {
  Box3 b;
  b.lo = {std::numeric_limits<float>::max(), std::numeric_limits<float>::max(),
          std::numeric_limits<float>::max()};
  b.hi = {std::numeric_limits<float>::lowest(), std::numeric_limits<float>::lowest(),
          std::numeric_limits<float>::lowest()};
  for (const TreeSlot& s : slots) {
    if (!s.tree) continue;
    for (int a = 0; a < 3; ++a) {
      b.lo[a] = std::min(b.lo[a], s.tree->header().bbox.lo[a]);
      b.hi[a] = std::max(b.hi[a], s.tree->header().bbox.hi[a]);
    }
  }
  t0.ForEach([&b](const Point& p) {
    const float c[3] = {p.x, p.y, p.z};
    for (int a = 0; a < 3; ++a) {
      b.lo[a] = std::min(b.lo[a], c[a]);
      b.hi[a] = std::max(b.hi[a], c[a]);
    }
  });
  return b;
}

std::string TreeFileName(uint32_t frame, uint64_t seq) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%08" PRIu32 "-%016" PRIx64 ".kdt", frame, seq);
  return buf;
}

bool ParseTreeFileName(const std::string& name, uint32_t* frame, uint64_t* seq) {
  // "ffffffff-ssssssssssssssss.kdt": 8 + 1 + 16 + 4 characters.
  if (name.size() != 29 || name.substr(25) != ".kdt" || name[8] != '-') return false;
  const std::string fpart = name.substr(0, 8), spart = name.substr(9, 16);
  char* end = nullptr;
  unsigned long f = std::strtoul(fpart.c_str(), &end, 10);
  if (*end != '\0') return false;
  unsigned long long s = std::strtoull(spart.c_str(), &end, 16);
  if (*end != '\0') return false;
  *frame = static_cast<uint32_t>(f);
  *seq = s;
  return true;
}

std::string FrameStateFileName(uint32_t frame) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%08" PRIu32 ".fst", frame);
  return buf;
}

std::string EncodeFrameState(const FrameVersion& v, uint64_t next_id) {
  Writer w;
  w.PutBytes(kFrameMagic, 8);
  w.Put<uint32_t>(kFrameVersion);
  w.Put<uint32_t>(v.frame);
  w.Put<uint64_t>(v.applied_lsn);
  w.Put<uint64_t>(next_id);
  w.Put<uint32_t>(static_cast<uint32_t>(v.slots.size()));
  for (const TreeSlot& s : v.slots) {
    w.Put<uint64_t>(s.tree ? s.tree->header().tree_seq : 0);
    uint32_t nd = s.dead ? static_cast<uint32_t>(s.dead->size()) : 0;
    w.Put<uint32_t>(nd);
    for (uint32_t i = 0; i < nd; ++i) w.Put<uint64_t>((*s.dead)[i]);
  }
  w.Put<uint32_t>(static_cast<uint32_t>(v.t0.size()));
  std::string recs(v.t0.size() * kPointRecordSize, '\0');
  EncodePoints(v.t0.ToVector(), reinterpret_cast<uint8_t*>(recs.data()));
  w.PutBytes(recs.data(), recs.size());
  w.Put<uint32_t>(crc32c::Mask(crc32c::Value(w.data().data(), w.data().size())));
  return std::move(w.data());
}

Result<FrameStateRecord> DecodeFrameState(const std::string& data, const std::string& what) {
  auto corrupt = [&](const std::string& m) { return Status::Corruption(what + ": " + m); };
  if (data.size() < 32) return corrupt("truncated (" + std::to_string(data.size()) + " bytes)");
  const auto* p = reinterpret_cast<const uint8_t*>(data.data());
  uint32_t stored = DecodeLE<uint32_t>(p + data.size() - 4);
  if (crc32c::Unmask(stored) != crc32c::Value(p, data.size() - 4)) {
    return corrupt("checksum mismatch");
  }
  Reader r(p, data.size() - 4);
  char magic[8];
  uint32_t version = 0, nslots = 0;
  FrameStateRecord rec;
  if (!r.GetBytes(magic, 8) || std::memcmp(magic, kFrameMagic, 8) != 0) return corrupt("bad magic");
  if (!r.Get(&version) || version != kFrameVersion) {
    return corrupt("unsupported version " + std::to_string(version));
  }
  if (!r.Get(&rec.frame) || !r.Get(&rec.applied_lsn) || !r.Get(&rec.next_id) || !r.Get(&nslots) ||
      nslots > 64) {
    return corrupt("bad header");
  }
  for (uint32_t i = 0; i < nslots; ++i) {
    uint64_t seq;
    uint32_t nd;
    if (!r.Get(&seq) || !r.Get(&nd) || r.remaining() < uint64_t{nd} * 8) return corrupt("bad slot");
    std::vector<uint64_t> dead(nd);
    for (uint32_t j = 0; j < nd; ++j) r.Get(&dead[j]);
    rec.tree_seqs.push_back(seq);
    rec.dead.push_back(std::move(dead));
  }
  uint32_t nt0;
  if (!r.Get(&nt0) || r.remaining() != uint64_t{nt0} * kPointRecordSize) {
    return corrupt("bad buffer size");
  }
  rec.t0.resize(nt0);
  DecodePoints(r.pos(), nt0, rec.t0.data());
  return rec;
}

}  // namespace hvdb
