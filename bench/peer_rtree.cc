#include "bench/peer_rtree.h"

#include <fcntl.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>

#include <spatialindex/SpatialIndex.h>

namespace hvdb::bench {

namespace si = SpatialIndex;

struct RTreePeer::Impl {
  si::IStorageManager* disk = nullptr;
  si::StorageManager::IBuffer* buffer = nullptr;
  si::ISpatialIndex* tree = nullptr;
  si::id_type index_id = 0;
  si::id_type next_id = 1;

  void Close() {
    delete tree;    // writes the tree header through the buffer
    delete buffer;  // flushes dirty nodes to the storage manager
    delete disk;    // flushes and closes the files
    tree = nullptr;
    buffer = nullptr;
    disk = nullptr;
  }
  ~Impl() { Close(); }
};

namespace {

[[noreturn]] void Fail(const std::string& what) {
  std::fprintf(stderr, "hvdb-bench: libspatialindex: %s\n", what.c_str());
  std::exit(1);
}

template <typename F>
void Guard(const char* what, F&& f) {
  try {
    f();
  } catch (Tools::Exception& e) {
    Fail(std::string(what) + ": " + e.what());
  } catch (const std::exception& e) {
    Fail(std::string(what) + ": " + e.what());
  }
}

void Coords(const Point& p, uint32_t dim, double fps, double* c) {
  c[0] = p.x;
  c[1] = p.y;
  c[2] = p.z;
  if (dim == 4) c[3] = p.frame / fps;
}

class PointStream : public si::IDataStream {
 public:
  PointStream(std::span<const Point> pts, uint32_t dim, double fps, si::id_type first_id)
      : pts_(pts), dim_(dim), fps_(fps), first_id_(first_id) {}
  si::IData* getNext() override {
    if (i_ >= pts_.size()) return nullptr;
    const Point& p = pts_[i_];
    double c[4];
    Coords(p, dim_, fps_, c);
    si::Region r(c, c, dim_);
    uint8_t rec[kPointRecordSize];
    EncodePoint(p, rec);
    auto id = static_cast<si::id_type>(first_id_ + static_cast<si::id_type>(i_));
    ++i_;
    return new si::RTree::Data(static_cast<uint32_t>(kPointRecordSize), rec, r, id);
  }
  bool hasNext() override { return i_ < pts_.size(); }
  uint32_t size() override { return static_cast<uint32_t>(pts_.size()); }
  void rewind() override { i_ = 0; }

 private:
  std::span<const Point> pts_;
  uint32_t dim_;
  double fps_;
  si::id_type first_id_;
  size_t i_ = 0;
};

class Collector : public si::IVisitor {
 public:
  explicit Collector(std::vector<Point>* out) : out_(out) {}
  void visitNode(const si::INode&) override {}
  void visitData(const si::IData& d) override {
    uint32_t len = 0;
    uint8_t* buf = nullptr;
    d.getData(len, &buf);  // a copy the caller owns
    if (len == kPointRecordSize) out_->push_back(DecodePoint(buf));
    delete[] buf;
  }
  void visitData(std::vector<const si::IData*>&) override {}

 private:
  std::vector<Point>* out_;
};

}  // namespace

RTreePeer::RTreePeer(std::string base, Params p)
    : base_(std::move(base)), p_(p), impl_(std::make_unique<Impl>()) {
  // A node holds its type, level, count and MBR, then per entry its MBR (2 * dim doubles), id
  // and data (length + bytes): size the capacities so that a full node fills one page.
  const uint32_t mbr = 2 * p_.dim * 8;
  const uint32_t header = 12 + mbr;
  leaf_cap_ = (p_.page_size - header) / (mbr + 8 + 4 + static_cast<uint32_t>(kPointRecordSize));
  index_cap_ = (p_.page_size - header) / (mbr + 8 + 4);
}

RTreePeer::~RTreePeer() = default;

void RTreePeer::OpenFresh() {
  for (const char* ext : {".idx", ".dat"}) ::unlink((base_ + ext).c_str());
  Guard("create storage", [&] {
    std::string name = base_;
    impl_->disk = si::StorageManager::createNewDiskStorageManager(name, p_.page_size);
    impl_->buffer =
        si::StorageManager::createNewRandomEvictionsBuffer(*impl_->disk, p_.buffer_pages, false);
  });
}

std::unique_ptr<RTreePeer> RTreePeer::Create(const std::string& base, const Params& p) {
  std::unique_ptr<RTreePeer> t(new RTreePeer(base, p));
  t->OpenFresh();
  Guard("create tree", [&] {
    t->impl_->tree = si::RTree::createNewRTree(*t->impl_->buffer, p.fill_factor, t->index_cap_,
                                               t->leaf_cap_, p.dim, si::RTree::RV_RSTAR,
                                               t->impl_->index_id);
  });
  return t;
}

std::unique_ptr<RTreePeer> RTreePeer::BulkLoad(const std::string& base, const Params& p,
                                               std::span<const Point> pts) {
  std::unique_ptr<RTreePeer> t(new RTreePeer(base, p));
  t->OpenFresh();
  PointStream stream(pts, p.dim, p.fps, t->impl_->next_id);
  Guard("bulk load", [&] {
    t->impl_->tree = si::RTree::createAndBulkLoadNewRTree(
        si::RTree::BLM_STR, stream, *t->impl_->buffer, p.fill_factor, t->index_cap_,
        t->leaf_cap_, p.dim, si::RTree::RV_RSTAR, t->impl_->index_id);
  });
  t->impl_->next_id += static_cast<si::id_type>(pts.size());
  return t;
}

void RTreePeer::Insert(std::span<const Point> pts) {
  Guard("insert", [&] {
    uint8_t rec[kPointRecordSize];
    double c[4];
    for (const Point& pt : pts) {
      Coords(pt, p_.dim, p_.fps, c);
      si::Point shape(c, p_.dim);
      EncodePoint(pt, rec);
      impl_->tree->insertData(static_cast<uint32_t>(kPointRecordSize), rec, shape,
                              impl_->next_id++);
    }
  });
}

void RTreePeer::Sync() {
  Guard("flush", [&] {
    impl_->tree->flush();  // the tree header
    // Dirty nodes -> storage manager. Not IBuffer::flush(): in libspatialindex 1.9.3 it deletes
    // the cached entries without removing them from its map (a later access double-frees);
    // clear() writes the dirty ones back and empties the buffer.
    impl_->buffer->clear();
    impl_->disk->flush();  // storage manager -> files (page cache)
  });
  for (const std::string& f : Files()) {
    int fd = ::open(f.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd >= 0) {
      ::fdatasync(fd);
      ::close(fd);
    }
  }
}

void RTreePeer::Close() { impl_->Close(); }

void RTreePeer::Reopen() {
  impl_->Close();
  Guard("reopen", [&] {
    std::string name = base_;
    impl_->disk = si::StorageManager::loadDiskStorageManager(name);
    impl_->buffer =
        si::StorageManager::createNewRandomEvictionsBuffer(*impl_->disk, p_.buffer_pages, false);
    impl_->tree = si::RTree::loadRTree(*impl_->buffer, impl_->index_id);
  });
}

uint64_t RTreePeer::Query(const double* lo, const double* hi, std::vector<Point>* out) {
  const size_t before = out->size();
  Guard("query", [&] {
    si::Region r(lo, hi, p_.dim);
    Collector c(out);
    impl_->tree->intersectsWithQuery(r, c);
  });
  return out->size() - before;
}

std::vector<std::string> RTreePeer::Files() const { return {base_ + ".idx", base_ + ".dat"}; }

}  // namespace hvdb::bench
