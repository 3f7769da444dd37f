// The second implementation of storage's I/O seam (storage/env.h): files as objects in a Ceph
// RADOS pool, through librados (Debian's librados-dev). A data directory becomes a name
// prefix in the pool; `rados -p POOL ls` shows the same names the POSIX store has as paths
// (docs/FORMAT.md, "On a RADOS pool"). A library of its own (hvdb_rados_env), so that storage/
// itself links no Ceph.
//
// What POSIX gives and RADOS does not is rebuilt on RADOS primitives:
//   - directories: an object "DIR/" whose omap keys are the entries (listed without a scan);
//   - atomic replacement (the manifest's rename): write_full of the new object, which RADOS
//     applies atomically, then the old name's removal;
//   - durability: librados returns once the OSDs committed the write, so Sync is a no-op;
//   - the data directory's lock: a RADOS exclusive lock with a lease that a thread renews, so
//     a dead process's lock expires instead of holding the data forever.
#ifndef HVDB_STORAGE_RADOS_ENV_H_
#define HVDB_STORAGE_RADOS_ENV_H_

#include <chrono>
#include <memory>
#include <string>

#include "storage/env.h"

namespace hvdb {

struct RadosSpec {
  std::string pool;
  std::string conf;  // ceph.conf of the cluster
  std::chrono::seconds lock_lease{20};  // a lock not renewed for this long is free again
  std::chrono::seconds op_timeout{30};  // an operation the cluster cannot serve fails after this
};

// "rados:POOL?conf=FILE[&lease=S][&timeout=S]" (FILE relative to the working directory).
Status ParseRadosSpec(const std::string& store, RadosSpec* spec);

// Connects to the cluster (creating the pool if it is missing). Operations that cannot reach
// the cluster fail after spec.op_timeout with IOError naming the object instead of hanging.
Result<std::unique_ptr<Env>> OpenRadosEnv(const RadosSpec& spec);

}  // namespace hvdb

#endif  // HVDB_STORAGE_RADOS_ENV_H_
