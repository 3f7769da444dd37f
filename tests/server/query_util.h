// Reading query results through the client library in server tests.
#ifndef HVDB_TESTS_SERVER_QUERY_UTIL_H_
#define HVDB_TESTS_SERVER_QUERY_UTIL_H_

#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "client/client.h"

namespace hvdb::testing {

// Every point of the stream, to its end; an error fails the test and ends the list.
inline std::vector<Point> Drain(client::QueryStream& q) {
  std::vector<Point> out;
  Batch b;
  for (;;) {
    auto more = q.Next(&b);
    EXPECT_TRUE(more.ok()) << more.status().ToString();
    if (!more.ok() || !*more) break;
    out.insert(out.end(), b.points.begin(), b.points.end());
  }
  return out;
}

// Runs the query and drains it.
inline std::vector<Point> All(client::Connection& c, const std::string& ds, const Region& r,
                              QueryOptions o = {}) {
  auto q = c.Query(ds, r, o);
  EXPECT_TRUE(q.ok()) << q.status().ToString();
  return q.ok() ? Drain(**q) : std::vector<Point>();
}

}  // namespace hvdb::testing

#endif  // HVDB_TESTS_SERVER_QUERY_UTIL_H_
