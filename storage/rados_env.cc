#include "storage/rados_env.h"

#include <rados/librados.h>
#include <sys/time.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <condition_variable>
#include <cstring>
#include <mutex>
#include <random>
#include <string>
#include <thread>

#include "storage/shared_library.h"

namespace hvdb {
namespace {

// librados, loaded when a RADOS store is opened (storage/shared_library.h), not linked: it and
// libceph-common are ~15 shared libraries with tens of thousands of relocations, which every
// start of hvdb-server paid, RADOS or not. HVDB_RADOS_SONAME: the library it was built with.
#define HVDB_RADOS_FUNCTIONS(X) \
  X(rados_aio_create_completion2) \
  X(rados_aio_get_return_value) \
  X(rados_aio_read) \
  X(rados_aio_release) \
  X(rados_aio_wait_for_complete) \
  X(rados_append) \
  X(rados_blocklist_add) \
  X(rados_buffer_free) \
  X(rados_conf_read_file) \
  X(rados_conf_set) \
  X(rados_connect) \
  X(rados_create) \
  X(rados_create_read_op) \
  X(rados_create_write_op) \
  X(rados_getaddrs) \
  X(rados_getxattr) \
  X(rados_ioctx_create) \
  X(rados_ioctx_destroy) \
  X(rados_lock_exclusive) \
  X(rados_omap_get_end) \
  X(rados_omap_get_next2) \
  X(rados_pool_create) \
  X(rados_pool_lookup) \
  X(rados_read) \
  X(rados_read_op_omap_get_keys2) \
  X(rados_read_op_operate) \
  X(rados_release_read_op) \
  X(rados_release_write_op) \
  X(rados_remove) \
  X(rados_rmxattr) \
  X(rados_setxattr) \
  X(rados_shutdown) \
  X(rados_stat) \
  X(rados_trunc) \
  X(rados_unlock) \
  X(rados_write) \
  X(rados_write_full) \
  X(rados_write_op_create) \
  X(rados_write_op_omap_rm_keys) \
  X(rados_write_op_omap_set) \
  X(rados_write_op_operate)

struct RadosLib {
#define HVDB_RADOS_MEMBER(name) decltype(&::name) name = nullptr;
  HVDB_RADOS_FUNCTIONS(HVDB_RADOS_MEMBER)
#undef HVDB_RADOS_MEMBER
};

RadosLib g_rados;

Status LoadRados() {
  static Status status;
  static std::once_flag once;
  std::call_once(once, [] {
    const std::string soname = HVDB_RADOS_SONAME;
    void* handle = nullptr;
    status = OpenSharedLibrary(soname, "a RADOS store", &handle);
#define HVDB_RADOS_LOAD(name) \
  if (status.ok()) status = SharedLibraryFunction(handle, soname, #name, &g_rados.name);
    HVDB_RADOS_FUNCTIONS(HVDB_RADOS_LOAD)
#undef HVDB_RADOS_LOAD
  });
  return status;
}

// The functions; only once LoadRados() succeeded (OpenRadosEnv, before any RadosEnv exists).
const RadosLib& Rados() { return g_rados; }

// Larger single ops than this are split (the OSD refuses ops above osd_max_write_size, 90 MB
// by default; reads are split alike to bound one op's memory on the OSD).
constexpr size_t kMaxOp = 16u << 20;

Status Err(const std::string& what, int ret) { return Status::FromErrno(what + " (rados)", -ret); }

// "a//b/./c/" -> "a/b/c": names as the POSIX store would resolve them.
std::string Normalize(const std::string& path) {
  std::string out = !path.empty() && path[0] == '/' ? "/" : "";
  size_t i = 0;
  while (i <= path.size()) {
    size_t j = path.find('/', i);
    if (j == std::string::npos) j = path.size();
    std::string part = path.substr(i, j - i);
    if (!part.empty() && part != ".") {
      if (!out.empty() && out.back() != '/') out += '/';
      out += part;
    }
    i = j + 1;
  }
  return out.empty() ? "." : out;
}

std::string DirObject(const std::string& dir) { return Normalize(dir) + "/"; }

std::string BaseName(const std::string& path) {
  size_t s = path.rfind('/');
  return s == std::string::npos ? path : path.substr(s + 1);
}

class RadosEnv;

class RadosReadFile : public RandomAccessFile {
 public:
  RadosReadFile(rados_ioctx_t io, std::string oid, uint64_t size)
      : io_(io), oid_(std::move(oid)), size_(size) {}

  Status Read(uint64_t offset, size_t n, void* dst) const override {
    auto* p = static_cast<char*>(dst);
    size_t done = 0;
    while (done < n) {
      size_t len = std::min(kMaxOp, n - done);
      int r = Rados().rados_read(io_, oid_.c_str(), p + done, len, offset + done);
      if (r < 0) return Err("read " + oid_, r);
      if (r == 0) break;
      done += static_cast<size_t>(r);
    }
    if (done < n) {
      return Status::Corruption("read " + oid_ + ": truncated at " + std::to_string(offset + done));
    }
    return Status::OK();
  }

  // Every buffer one asynchronous read, all issued before the first wait: the OSDs serve
  // them in parallel, as io_uring lets a disk do for the POSIX store.
  void ReadBatch(std::span<ReadRequest> requests) const override {
    struct Op {
      rados_completion_t c = nullptr;
      size_t request = 0;
      size_t len = 0;
    };
    std::vector<Op> ops;
    for (size_t i = 0; i < requests.size(); ++i) {
      ReadRequest& r = requests[i];
      r.status = Status::OK();
      uint64_t off = r.offset;
      for (std::span<uint8_t> buf : r.buffers) {
        for (size_t done = 0; done < buf.size();) {
          size_t len = std::min(kMaxOp, buf.size() - done);
          Op op{nullptr, i, len};
          int rc = Rados().rados_aio_create_completion2(nullptr, nullptr, &op.c);
          if (rc == 0) {
            rc = Rados().rados_aio_read(io_, oid_.c_str(), op.c,
                                reinterpret_cast<char*>(buf.data() + done), len, off + done);
          }
          if (rc < 0) {
            if (op.c) Rados().rados_aio_release(op.c);
            if (r.status.ok()) r.status = Err("read " + oid_, rc);
          } else {
            ops.push_back(op);
          }
          done += len;
        }
        off += buf.size();
      }
    }
    for (Op& op : ops) {
      Rados().rados_aio_wait_for_complete(op.c);
      int rc = Rados().rados_aio_get_return_value(op.c);
      Rados().rados_aio_release(op.c);
      Status& st = requests[op.request].status;
      if (!st.ok()) continue;
      if (rc < 0) {
        st = Err("read " + oid_, rc);
      } else if (static_cast<size_t>(rc) < op.len) {
        st = Status::Corruption("read " + oid_ + ": truncated");
      }
    }
  }

  void DropCache() const override {}  // OSDs cache on their side; nothing to drop here
  uint64_t size() const override { return size_; }
  const std::string& path() const override { return oid_; }

 private:
  rados_ioctx_t io_;
  std::string oid_;
  uint64_t size_;
};

class RadosWriteFile : public WritableFile {
 public:
  RadosWriteFile(rados_ioctx_t io, std::string oid, uint64_t size)
      : io_(io), oid_(std::move(oid)), size_(size) {}

  // One append is one RADOS op (atomic: all of it or none) when it fits one op.
  Status Append(std::string_view data) override {
    for (size_t done = 0; done < data.size();) {
      size_t len = std::min(kMaxOp, data.size() - done);
      int r = Rados().rados_append(io_, oid_.c_str(), data.data() + done, len);
      if (r < 0) {
        if (done > 0) (void)Rados().rados_trunc(io_, oid_.c_str(), size_);  // nothing of it stays
        return Err("append " + oid_, r);
      }
      done += len;
    }
    size_ += data.size();
    return Status::OK();
  }
  Status WriteAt(uint64_t offset, std::string_view data) override {
    for (size_t done = 0; done < data.size();) {
      size_t len = std::min(kMaxOp, data.size() - done);
      int r = Rados().rados_write(io_, oid_.c_str(), data.data() + done, len, offset + done);
      if (r < 0) return Err("write " + oid_, r);
      done += len;
    }
    size_ = std::max<uint64_t>(size_, offset + data.size());
    return Status::OK();
  }
  // librados returns from a write once the OSDs have committed it.
  Status Sync() override { return Status::OK(); }
  Status Truncate(uint64_t size) override {
    int r = Rados().rados_trunc(io_, oid_.c_str(), size);
    if (r < 0) return Err("truncate " + oid_, r);
    size_ = size;
    return Status::OK();
  }
  uint64_t size() const override { return size_; }
  const std::string& path() const override { return oid_; }

 private:
  rados_ioctx_t io_;
  std::string oid_;
  uint64_t size_;
};

// The data directory's lock: an exclusive RADOS lock with a lease, renewed by a thread at a
// third of the lease. If this process dies the lease runs out and another process may lock.
class RadosLock : public FileLock {
 public:
  RadosLock(rados_ioctx_t io, std::string oid, std::string cookie, std::chrono::seconds lease)
      : io_(io), oid_(std::move(oid)), cookie_(std::move(cookie)), lease_(lease) {
    renewer_ = std::thread([this] { Renew(); });
  }
  ~RadosLock() override {
    {
      std::lock_guard<std::mutex> l(mu_);
      stop_ = true;
    }
    cv_.notify_all();
    renewer_.join();
    // A clean release: the next holder has nobody to fence.
    (void)Rados().rados_rmxattr(io_, oid_.c_str(), kHolderXattr);
    (void)Rados().rados_unlock(io_, oid_.c_str(), kName, cookie_.c_str());
  }
  static constexpr const char* kHolderXattr = "hvdb.holder";
  static constexpr const char* kName = "hvdb";

 private:
  void Renew() {
    std::unique_lock<std::mutex> l(mu_);
    while (!cv_.wait_for(l, lease_ / 3, [this] { return stop_; })) {
      timeval tv{static_cast<time_t>(lease_.count()), 0};
      (void)Rados().rados_lock_exclusive(io_, oid_.c_str(), kName, cookie_.c_str(), "hvdb data", &tv,
                                 LIBRADOS_LOCK_FLAG_MAY_RENEW);
    }
  }

  rados_ioctx_t io_;
  std::string oid_, cookie_;
  std::chrono::seconds lease_;
  std::mutex mu_;
  std::condition_variable cv_;
  bool stop_ = false;
  std::thread renewer_;
};

class RadosEnv : public Env {
 public:
  RadosEnv(rados_t cluster, rados_ioctx_t io, RadosSpec spec)
      : cluster_(cluster), io_(io), spec_(std::move(spec)) {}
  ~RadosEnv() override {
    Rados().rados_ioctx_destroy(io_);
    Rados().rados_shutdown(cluster_);
  }

  Result<std::shared_ptr<RandomAccessFile>> OpenRead(const std::string& path) override {
    std::string oid = Normalize(path);
    uint64_t size = 0;
    time_t mtime = 0;
    int r = Rados().rados_stat(io_, oid.c_str(), &size, &mtime);
    if (r < 0) return Err("open " + oid, r);
    return std::shared_ptr<RandomAccessFile>(new RadosReadFile(io_, oid, size));
  }

  Result<std::unique_ptr<WritableFile>> OpenWrite(const std::string& path, bool truncate) override {
    std::string oid = Normalize(path);
    uint64_t size = 0;
    int r;
    if (truncate) {
      r = Rados().rados_write_full(io_, oid.c_str(), "", 0);
    } else {
      rados_write_op_t op = Rados().rados_create_write_op();
      Rados().rados_write_op_create(op, LIBRADOS_CREATE_IDEMPOTENT, nullptr);
      r = Rados().rados_write_op_operate(op, io_, oid.c_str(), nullptr, 0);
      Rados().rados_release_write_op(op);
      time_t mtime = 0;
      if (r >= 0) r = Rados().rados_stat(io_, oid.c_str(), &size, &mtime);
    }
    if (r < 0) return Err("open " + oid, r);
    HVDB_RETURN_IF_ERROR(AddEntry(oid));
    return std::unique_ptr<WritableFile>(new RadosWriteFile(io_, oid, size));
  }

  // RADOS has no rename: the content goes to the new name by write_full (atomic: a reader
  // sees the old or the new object, never a mix), then the old name goes.
  Status Rename(const std::string& from, const std::string& to) override {
    std::string src = Normalize(from), dst = Normalize(to);
    if (IsDir(src)) {
      return Status::Unsupported("rename " + src + ": the RADOS store renames files, not "
                                 "directories (AtomicDirRename() is false)");
    }
    HVDB_ASSIGN_OR_RETURN(auto f, OpenRead(src));
    std::string data(f->size(), '\0');
    HVDB_RETURN_IF_ERROR(f->Read(0, data.size(), data.data()));
    HVDB_RETURN_IF_ERROR(WriteWhole(dst, data));
    HVDB_RETURN_IF_ERROR(AddEntry(dst));
    return Remove(src);
  }

  Status Remove(const std::string& path) override {
    std::string oid = Normalize(path);
    HVDB_RETURN_IF_ERROR(RemoveEntry(oid));  // first out of the listing, then gone
    int r = Rados().rados_remove(io_, oid.c_str());
    if (r < 0 && r != -ENOENT) return Err("remove " + oid, r);
    return Status::OK();
  }

  Status SyncDir(const std::string&) override { return Status::OK(); }
  bool AtomicDirRename() const override { return false; }

  Status CreateDirs(const std::string& dir) override {
    std::string d = Normalize(dir);
    if (d == "." || d == "/") return Status::OK();
    std::string parent = ParentDir(d);
    if (parent != d && !Exists(parent)) HVDB_RETURN_IF_ERROR(CreateDirs(parent));
    rados_write_op_t op = Rados().rados_create_write_op();
    Rados().rados_write_op_create(op, LIBRADOS_CREATE_IDEMPOTENT, nullptr);
    int r = Rados().rados_write_op_operate(op, io_, DirObject(d).c_str(), nullptr, 0);
    Rados().rados_release_write_op(op);
    if (r < 0) return Err("mkdir " + d, r);
    return AddEntry(d + "/");
  }

  Result<std::vector<std::string>> ListDir(const std::string& dir) override {
    std::string obj = DirObject(dir);
    std::vector<std::string> names;
    std::string after;
    for (;;) {
      rados_read_op_t op = Rados().rados_create_read_op();
      rados_omap_iter_t it = nullptr;
      unsigned char more = 0;
      int prval = 0;
      Rados().rados_read_op_omap_get_keys2(op, after.c_str(), 1000, &it, &more, &prval);
      int r = Rados().rados_read_op_operate(op, io_, obj.c_str(), 0);
      if (r >= 0 && prval < 0) r = prval;
      if (r < 0) {
        if (it) Rados().rados_omap_get_end(it);
        Rados().rados_release_read_op(op);
        return Err("list " + Normalize(dir), r);
      }
      char *key = nullptr, *val = nullptr;
      size_t klen = 0, vlen = 0;
      while (Rados().rados_omap_get_next2(it, &key, &val, &klen, &vlen) == 0 && key != nullptr) {
        after.assign(key, klen);
        std::string name = after;
        if (!name.empty() && name.back() == '/') name.pop_back();
        names.push_back(name);
      }
      Rados().rados_omap_get_end(it);
      Rados().rados_release_read_op(op);
      if (!more) break;
    }
    return names;
  }

  Status RemoveTree(const std::string& dir) override {
    std::string d = Normalize(dir);
    auto names = ListDir(d);
    if (!names.ok()) return names.status().code() == StatusCode::kNotFound ? Status::OK() : names.status();
    for (const std::string& n : *names) {
      const std::string child = d + "/" + n;
      if (IsDir(child)) {
        HVDB_RETURN_IF_ERROR(RemoveTree(child));
      } else {
        HVDB_RETURN_IF_ERROR(Remove(child));
      }
    }
    HVDB_RETURN_IF_ERROR(RemoveEntry(d + "/"));
    int r = Rados().rados_remove(io_, DirObject(d).c_str());
    if (r < 0 && r != -ENOENT) return Err("rmdir " + d, r);
    return Status::OK();
  }

  bool Exists(const std::string& path) override {
    std::string oid = Normalize(path);
    uint64_t size;
    time_t mtime;
    return Rados().rados_stat(io_, oid.c_str(), &size, &mtime) == 0 || IsDir(oid);
  }

  Result<std::unique_ptr<FileLock>> Lock(const std::string& path) override {
    std::string oid = Normalize(path);
    // The cookie names this holder: host, process and a random part.
    char host[256] = "host";
    gethostname(host, sizeof host - 1);
    std::string cookie = std::string(host) + ":" + std::to_string(getpid()) + ":" +
                         std::to_string(std::random_device{}());
    timeval tv{static_cast<time_t>(spec_.lock_lease.count()), 0};
    int r = Rados().rados_lock_exclusive(io_, oid.c_str(), RadosLock::kName, cookie.c_str(), "hvdb data",
                                 &tv, 0);
    if (r == -EBUSY || r == -EEXIST) {
      return Status::IOError("lock " + oid + ": held by another process (it expires " +
                                 std::to_string(spec_.lock_lease.count()) +
                                 " s after its holder stops renewing it)");
    }
    if (r < 0) return Err("lock " + oid, r);
    Status fenced = FencePreviousHolder(oid);
    if (!fenced.ok()) {
      (void)Rados().rados_unlock(io_, oid.c_str(), RadosLock::kName, cookie.c_str());
      return fenced;
    }
    HVDB_RETURN_IF_ERROR(AddEntry(oid));
    return std::unique_ptr<FileLock>(new RadosLock(io_, oid, cookie, spec_.lock_lease));
  }

 private:
  // Fencing: the lock's object names its holder's client address (xattr). A holder whose lease
  // ran out may only be paused (a stalled process, a partitioned host) and could write again
  // when it wakes; the new holder has the cluster refuse that client's every op (the OSD
  // blocklist, as RBD's exclusive lock does) before it writes anything itself.
  Status FencePreviousHolder(const std::string& oid) {
    char* mine = nullptr;
    int r = Rados().rados_getaddrs(cluster_, &mine);
    if (r < 0) return Err("own address", r);
    std::string own = mine;
    Rados().rados_buffer_free(mine);
    char prev[1024];
    int n = Rados().rados_getxattr(io_, oid.c_str(), RadosLock::kHolderXattr, prev, sizeof prev - 1);
    if (n > 0) {
      std::string holder(prev, static_cast<size_t>(n));
      if (holder != own) {
        // "[v2:127.0.0.1:0/1234,v1:...]": one entry names the client instance.
        std::string addr = holder;
        addr.erase(std::remove(addr.begin(), addr.end(), '['), addr.end());
        addr.erase(std::remove(addr.begin(), addr.end(), ']'), addr.end());
        addr = addr.substr(0, addr.find(','));
        if (addr.compare(0, 3, "v2:") == 0 || addr.compare(0, 3, "v1:") == 0) addr = addr.substr(3);
        r = Rados().rados_blocklist_add(cluster_, addr.data(), 3600);
        if (r < 0) {
          return Err("lock " + oid + ": cannot fence the previous holder " + holder +
                     " (refusing to take over while it might still write)", r);
        }
      }
    }
    r = Rados().rados_setxattr(io_, oid.c_str(), RadosLock::kHolderXattr, own.data(), own.size());
    if (r < 0) return Err("lock " + oid + ": recording the holder", r);
    return Status::OK();
  }

 public:
  Status WriteNewFile(const std::string& path, std::string_view data, bool) override {
    std::string oid = Normalize(path);
    HVDB_RETURN_IF_ERROR(WriteWhole(oid, data));
    return AddEntry(oid);
  }

 private:
  bool IsDir(const std::string& path) {
    uint64_t size;
    time_t mtime;
    return Rados().rados_stat(io_, DirObject(path).c_str(), &size, &mtime) == 0;
  }

  // The object's whole content: one atomic write_full when it fits one op; larger ones are
  // written in pieces to an object nothing refers to yet (trees are written before the
  // manifest that names them).
  Status WriteWhole(const std::string& oid, std::string_view data) {
    int r = Rados().rados_write_full(io_, oid.c_str(), data.data(), std::min(kMaxOp, data.size()));
    if (r < 0) return Err("write " + oid, r);
    for (size_t done = kMaxOp; done < data.size(); done += kMaxOp) {
      r = Rados().rados_write(io_, oid.c_str(), data.data() + done, std::min(kMaxOp, data.size() - done),
                      done);
      if (r < 0) return Err("write " + oid, r);
    }
    return Status::OK();
  }

  // Directory entries: omap keys of the parent's "DIR/" object (a subdirectory's key ends
  // in '/').
  struct Entry {
    std::string parent, key;
  };
  static Entry EntryOf(const std::string& name) {
    const bool dir = name.back() == '/';
    std::string plain = dir ? name.substr(0, name.size() - 1) : name;
    return {ParentDir(plain), BaseName(plain) + (dir ? "/" : "")};
  }
  Status AddEntry(const std::string& name) {
    Entry e = EntryOf(name);
    const char* keys[] = {e.key.c_str()};
    const char* vals[] = {""};
    size_t lens[] = {0};
    rados_write_op_t op = Rados().rados_create_write_op();
    Rados().rados_write_op_create(op, LIBRADOS_CREATE_IDEMPOTENT, nullptr);
    Rados().rados_write_op_omap_set(op, keys, vals, lens, 1);
    int r = Rados().rados_write_op_operate(op, io_, DirObject(e.parent).c_str(), nullptr, 0);
    Rados().rados_release_write_op(op);
    if (r < 0) return Err("add " + name + " to " + e.parent, r);
    return Status::OK();
  }
  Status RemoveEntry(const std::string& name) {
    Entry e = EntryOf(name);
    const char* keys[] = {e.key.c_str()};
    rados_write_op_t op = Rados().rados_create_write_op();
    Rados().rados_write_op_omap_rm_keys(op, keys, 1);
    int r = Rados().rados_write_op_operate(op, io_, DirObject(e.parent).c_str(), nullptr, 0);
    Rados().rados_release_write_op(op);
    if (r < 0 && r != -ENOENT) return Err("remove " + name + " from " + e.parent, r);
    return Status::OK();
  }

  rados_t cluster_;
  rados_ioctx_t io_;
  RadosSpec spec_;
};

}  // namespace

Status ParseRadosSpec(const std::string& store, RadosSpec* spec) {
  const std::string prefix = "rados:";
  if (store.compare(0, prefix.size(), prefix) != 0) {
    return Status::InvalidArgument("store '" + store + "': expected rados:POOL?conf=FILE");
  }
  std::string rest = store.substr(prefix.size());
  size_t q = rest.find('?');
  spec->pool = rest.substr(0, q);
  if (spec->pool.empty()) return Status::InvalidArgument("store '" + store + "': no pool name");
  spec->conf.clear();
  if (q != std::string::npos) {
    std::string params = rest.substr(q + 1);
    size_t i = 0;
    while (i <= params.size()) {
      size_t amp = params.find('&', i);
      if (amp == std::string::npos) amp = params.size();
      std::string kv = params.substr(i, amp - i);
      size_t eq = kv.find('=');
      std::string k = kv.substr(0, eq), v = eq == std::string::npos ? "" : kv.substr(eq + 1);
      if (k == "conf") {
        spec->conf = v;
      } else if (k == "lease") {
        int s = std::atoi(v.c_str());
        if (s < 3 || s > 3600) return Status::InvalidArgument("store: lease must be 3..3600 s");
        spec->lock_lease = std::chrono::seconds(s);
      } else if (k == "timeout") {
        int s = std::atoi(v.c_str());
        if (s < 1 || s > 3600) return Status::InvalidArgument("store: timeout must be 1..3600 s");
        spec->op_timeout = std::chrono::seconds(s);
      } else if (!k.empty()) {
        return Status::InvalidArgument("store '" + store + "': unknown parameter '" + k +
                                       "' (conf, lease, timeout)");
      }
      i = amp + 1;
    }
  }
  if (spec->conf.empty()) {
    return Status::InvalidArgument("store '" + store + "': give the cluster's ceph.conf as "
                                   "rados:POOL?conf=FILE");
  }
  return Status::OK();
}

Result<std::unique_ptr<Env>> OpenRadosEnv(const RadosSpec& spec) {
  if (access(spec.conf.c_str(), R_OK) != 0) {
    return Status::FromErrno("ceph configuration " + spec.conf, errno);
  }
  HVDB_RETURN_IF_ERROR(LoadRados());
  rados_t cluster = nullptr;
  int r = Rados().rados_create(&cluster, nullptr);
  if (r < 0) return Err("rados_create", r);
  auto fail = [&](const std::string& what, int rc) {
    Rados().rados_shutdown(cluster);
    return Err(what, rc);
  };
  if ((r = Rados().rados_conf_read_file(cluster, spec.conf.c_str())) < 0) return fail("read " + spec.conf, r);
  // Fail operations the cluster cannot serve instead of waiting for ever.
  const std::string timeout = std::to_string(spec.op_timeout.count());
  Rados().rados_conf_set(cluster, "client_mount_timeout", timeout.c_str());
  Rados().rados_conf_set(cluster, "rados_mon_op_timeout", timeout.c_str());
  Rados().rados_conf_set(cluster, "rados_osd_op_timeout", timeout.c_str());
  Rados().rados_conf_set(cluster, "log_to_stderr", "false");
  if ((r = Rados().rados_connect(cluster)) < 0) return fail("connect to the cluster of " + spec.conf, r);
  if (Rados().rados_pool_lookup(cluster, spec.pool.c_str()) < 0) {
    r = Rados().rados_pool_create(cluster, spec.pool.c_str());
    if (r < 0 && r != -EEXIST) return fail("create pool " + spec.pool, r);
  }
  rados_ioctx_t io = nullptr;
  if ((r = Rados().rados_ioctx_create(cluster, spec.pool.c_str(), &io)) < 0) {
    return fail("open pool " + spec.pool, r);
  }
  return std::unique_ptr<Env>(new RadosEnv(cluster, io, spec));
}

}  // namespace hvdb
