// The RADOS store of the tests: a real cluster started by scripts/ceph-dev.sh (CTest fixture
// `ceph`), named by $HVDB_CEPH_CONF. Without it the tests fail: they are never skipped.
#ifndef HVDB_TESTS_STORAGE_RADOS_TEST_UTIL_H_
#define HVDB_TESTS_STORAGE_RADOS_TEST_UTIL_H_

#include <cstdlib>
#include <memory>
#include <string>

#include <gtest/gtest.h>

#include "storage/rados_env.h"

namespace hvdb::testing {

inline std::string CephConf() {
  const char* c = std::getenv("HVDB_CEPH_CONF");
  return c ? c : "";
}

// One connection for the whole test binary (pool "hvdb-tests").
inline Env* RadosTestEnv() {
  static Env* env = [] {
    const std::string conf = CephConf();
    if (conf.empty()) {
      ADD_FAILURE() << "HVDB_CEPH_CONF is not set: run through CTest (fixture `ceph` starts a "
                       "cluster with scripts/ceph-dev.sh)";
      return static_cast<Env*>(nullptr);
    }
    RadosSpec spec;
    spec.pool = "hvdb-tests";
    spec.conf = conf;
    spec.lock_lease = std::chrono::seconds(6);
    auto e = OpenRadosEnv(spec);
    if (!e.ok()) {
      ADD_FAILURE() << e.status().ToString();
      return static_cast<Env*>(nullptr);
    }
    return e->release();
  }();
  return env;
}

}  // namespace hvdb::testing

#endif  // HVDB_TESTS_STORAGE_RADOS_TEST_UTIL_H_
