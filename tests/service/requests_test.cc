// The request table (service/requests.h): every kind of the protocol has exactly one row, the
// unary kinds' ops round-trip their values through the wire, and ExecuteUnary answers each unary
// kind through the executor (and refuses the others as MALFORMED).
#include "service/requests.h"

#include <gtest/gtest.h>

#include <cstring>

#include <filesystem>
#include <set>

#include "service/service.h"

namespace hvdb::service {
namespace {

namespace fs = std::filesystem;

TEST(RequestTableTest, EveryKindOfTheProtocolHasOneRow) {
  const google::protobuf::OneofDescriptor* body =
      wire::Request::descriptor()->FindOneofByName("body");
  ASSERT_NE(body, nullptr);
  std::set<int> fields;
  for (int i = 0; i < body->field_count(); ++i) fields.insert(body->field(i)->number());
  std::set<int> rows;
  std::set<std::string> names;
  for (const RequestKind& k : Requests()) {
    EXPECT_TRUE(rows.insert(k.body).second) << k.name << ": two rows for one body";
    EXPECT_TRUE(names.insert(k.name).second) << k.name << ": two rows of one name";
    EXPECT_TRUE(fields.count(k.body)) << k.name << ": no such field in Request.body";
  }
  EXPECT_EQ(rows, fields) << "a kind of Request.body without a row in HVDB_REQUESTS";
}

TEST(RequestTableTest, KindOfFindsTheRowAndNamesTheUnknown) {
  wire::Request r;
  r.mutable_compact()->set_dataset("d");
  EXPECT_STREQ(KindOf(r).name, "compact");
  EXPECT_TRUE(KindOf(r).writes);
  EXPECT_EQ(KindOf(r).flow, Flow::kUnary);
  r.mutable_query();
  EXPECT_STREQ(KindOf(r).name, "query");
  EXPECT_FALSE(KindOf(r).writes);
  EXPECT_EQ(KindOf(r).flow, Flow::kStream);
  r.clear_body();
  EXPECT_STREQ(KindOf(r).name, "unknown");
  EXPECT_EQ(KindOf(r).flow, Flow::kConnection);
}

TEST(RequestTableTest, OpsRoundTripTheirValues) {
  // A request and its reply through the op's pairs, as the remote backend and the server use
  // them.
  op::Compact::In c{"d", {3, 9, true}};
  wire::Request req;
  op::Compact::Put(c, &req);
  auto back = op::Compact::Take(req);
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  EXPECT_EQ(back->dataset, "d");
  EXPECT_EQ(back->value.first, 3u);
  EXPECT_EQ(back->value.last, 9u);
  EXPECT_TRUE(back->value.photos);
  EXPECT_TRUE(op::Compact::Repeatable(c));

  op::Copy::In copy{"d", {2, std::nullopt, "clip", true}};
  EXPECT_FALSE(op::Copy::Repeatable(copy)) << "a cut deletes: not safe to repeat";
  copy.value.cut = false;
  EXPECT_TRUE(op::Copy::Repeatable(copy));

  ServerCounters sc;
  sc.connections_open = 3;
  sc.role = "reader";
  sc.leader = "127.0.0.1:7000";
  sc.requests = {{"query", 5, 1, 2, 3}, {"edit", 1, 4, 5, 6}};
  wire::Response resp;
  op::ServerStats::PutReply(sc, &resp);
  auto got = op::ServerStats::TakeReply(resp);
  ASSERT_TRUE(got.ok());
  EXPECT_EQ(got->connections_open, 3u);
  EXPECT_EQ(got->role, "reader");
  EXPECT_EQ(got->leader, "127.0.0.1:7000");
  ASSERT_EQ(got->requests.size(), 2u);
  EXPECT_EQ(got->requests[0].kind, "edit");  // sorted by kind
  EXPECT_EQ(got->requests[1].p99_ms, 3);

  // A reply of another body is the server's mistake, said as such.
  wire::Response other;
  other.mutable_ack();
  EXPECT_TRUE(op::Describe::TakeReply(other).status().IsCorruption());
}

class ExecuteUnaryTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = (fs::temp_directory_path() /
            ("hvdb_requests_test_" + std::to_string(::getpid()))).string();
    fs::remove_all(dir_);
    auto db = Database::Open(dir_, {});
    ASSERT_TRUE(db.ok()) << db.status().ToString();
    db_ = std::move(db).value();
    x_ = std::make_unique<Service>(db_.get(), dir_);
  }
  void TearDown() override {
    x_.reset();
    db_.reset();
    fs::remove_all(dir_);
  }
  std::string dir_;
  std::unique_ptr<Database> db_;
  std::unique_ptr<Service> x_;
};

TEST_F(ExecuteUnaryTest, AnswersEachUnaryKindThroughTheExecutor) {
  DatasetInfo info;
  info.name = "d";
  info.fps = 30;
  wire::Request create;
  create.set_id(7);
  op::Create::Put(info, &create);
  wire::Response r = ExecuteUnary(*x_, create);
  EXPECT_EQ(r.id(), 7u);
  ASSERT_TRUE(r.has_info()) << r.DebugString();
  EXPECT_EQ(r.info().name(), "d");

  wire::Request list;
  op::List::Put({}, &list);
  auto names = op::List::TakeReply(ExecuteUnary(*x_, list));
  ASSERT_TRUE(names.ok());
  EXPECT_EQ(*names, std::vector<std::string>{"d"});

  // An unknown dataset is UNKNOWN_DATASET, in the executor's words.
  wire::Request describe;
  op::Describe::Put("nope", &describe);
  r = ExecuteUnary(*x_, describe);
  ASSERT_TRUE(r.has_error());
  EXPECT_EQ(r.error().code(), wire::UNKNOWN_DATASET);

  // server_stats: the process's counters, from the source the server sets.
  wire::Request ss;
  op::ServerStats::Put({}, &ss);
  auto plain = op::ServerStats::TakeReply(ExecuteUnary(*x_, ss));
  ASSERT_TRUE(plain.ok());
  EXPECT_TRUE(plain->role.empty());
  x_->SetCounters([] {
    ServerCounters c;
    c.role = "writer";
    c.connections_total = 42;
    return c;
  });
  auto served = op::ServerStats::TakeReply(ExecuteUnary(*x_, ss));
  ASSERT_TRUE(served.ok());
  EXPECT_EQ(served->role, "writer");
  EXPECT_EQ(served->connections_total, 42u);
}

TEST_F(ExecuteUnaryTest, ReadGaussiansAnswersTheRecordsAndWhichAreStored) {
  DatasetInfo info;
  info.name = "g";
  info.fps = 30;
  info.gaussians = true;
  wire::Request create;
  op::Create::Put(info, &create);
  auto made = op::Create::TakeReply(ExecuteUnary(*x_, create));
  ASSERT_TRUE(made.ok());
  EXPECT_TRUE(made->gaussians);
  std::vector<Point> pts(3);
  GaussianColumns cols;
  cols.sh_degree = 1;
  cols.values.resize(3 * cols.stride());
  for (size_t i = 0; i < cols.values.size(); ++i) cols.values[i] = 0.25f * static_cast<float>(i);
  for (size_t i = 0; i < 3; ++i) {
    pts[i].x = static_cast<float>(i);
    pts[i].cov = GaussianCovariance(cols.record(i));
    pts[i].flags = kFlagHasCovariance;
  }
  ASSERT_TRUE(x_->BulkLoad("g", 0, pts, &cols).ok());
  // A plain point load into a Gaussian dataset is refused: its records would be missing.
  auto plain = x_->BulkLoad("g", 1, pts);
  ASSERT_FALSE(plain.ok());
  EXPECT_NE(plain.status().message().find("Gaussian splats"), std::string::npos);

  wire::Request req;
  op::ReadGaussians::Put({"g", {3, 1, 999}}, &req);  // ids 1..3 were issued; 999 was not
  auto got = op::ReadGaussians::TakeReply(ExecuteUnary(*x_, req));
  ASSERT_TRUE(got.ok()) << got.status().ToString();
  EXPECT_EQ(got->found, (std::vector<bool>{true, true, false}));
  ASSERT_EQ(got->records.size(), 3u);
  EXPECT_EQ(got->records.sh_degree, 1);
  EXPECT_EQ(0, std::memcmp(got->records.record(0), cols.record(2), 4 * cols.stride()));
  EXPECT_EQ(0, std::memcmp(got->records.record(1), cols.record(0), 4 * cols.stride()));
  EXPECT_EQ(got->records.record(2)[kGsOpacity], 0.f);

  // Ids that are not whole u64s, or too many: the request's shape is wrong.
  req.mutable_read_gaussians()->mutable_ids()->push_back('x');
  wire::Response r = ExecuteUnary(*x_, req);
  ASSERT_TRUE(r.has_error());
  EXPECT_NE(r.error().message().find("multiple of 8"), std::string::npos);
}

TEST_F(ExecuteUnaryTest, RefusesWhatIsNotUnary) {
  for (const RequestKind& k : Requests()) {
    if (k.flow == Flow::kUnary) continue;
    wire::Request req;
    const auto* field = wire::Request::descriptor()->FindFieldByNumber(k.body);
    ASSERT_NE(field, nullptr) << k.name;
    req.GetReflection()->MutableMessage(&req, field);
    wire::Response r = ExecuteUnary(*x_, req);
    ASSERT_TRUE(r.has_error()) << k.name;
    EXPECT_EQ(r.error().code(), wire::MALFORMED) << k.name;
  }
}

}  // namespace
}  // namespace hvdb::service
