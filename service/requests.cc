#include "service/requests.h"

#include "storage/coding.h"

#include <algorithm>
#include <array>

namespace hvdb::service {

namespace {

#define HVDB_ROW(OP, BODY, NAME, WRITES, FLOW, REPEATABLE, TOO_LARGE) \
  RequestKind{wire::Request::BODY, NAME, WRITES, Flow::FLOW, REPEATABLE, TOO_LARGE},
constexpr RequestKind kTable[] = {HVDB_REQUESTS(HVDB_ROW)};
#undef HVDB_ROW

constexpr RequestKind kUnknown{wire::Request::BODY_NOT_SET, "unknown", false, Flow::kConnection,
                               false, nullptr};

// The row of each body case, found without a search: body cases are the proto's field numbers.
constexpr size_t kMaxBody = 64;
constexpr std::array<const RequestKind*, kMaxBody> MakeIndex() {
  std::array<const RequestKind*, kMaxBody> index{};
  for (const RequestKind& k : kTable) index[static_cast<size_t>(k.body)] = &k;
  return index;
}
constexpr std::array<const RequestKind*, kMaxBody> kIndex = MakeIndex();

constexpr char kUnknownDataset[] = "no dataset '";

const RequestKind& Row(wire::Request::BodyCase body) {
  const RequestKind* k = kIndex[static_cast<size_t>(body)];
  return *k;
}

}  // namespace

std::span<const RequestKind> Requests() { return kTable; }

const RequestKind& KindOf(const wire::Request& r) {
  const auto body = static_cast<size_t>(r.body_case());
  if (body >= kMaxBody || kIndex[body] == nullptr) return kUnknown;
  return *kIndex[body];
}

Status UnknownDataset(const std::string& name) {
  return Status::NotFound(kUnknownDataset + name + "' (the datasets request lists them)");
}

bool IsUnknownDataset(const Status& s) {
  return s.IsNotFound() && s.message().rfind(kUnknownDataset, 0) == 0;
}

wire::Response ErrorResponse(uint64_t id, const Status& st, wire::ErrorCode code) {
  wire::Response r;
  r.set_id(id);
  wire::ToWire(st, r.mutable_error());
  if (code == wire::ERROR_UNSPECIFIED && IsUnknownDataset(st)) code = wire::UNKNOWN_DATASET;
  if (code != wire::ERROR_UNSPECIFIED) r.mutable_error()->set_code(code);
  return r;
}

// ---- Server counters: the same fields in ServerCounters and StatsReply.

namespace {

template <typename M>
void PutCounters(const ServerCounters& c, M* out) {
  out->set_connections_open(c.connections_open);
  out->set_connections_total(c.connections_total);
  out->set_bytes_in(c.bytes_in);
  out->set_bytes_out(c.bytes_out);
  out->set_cache_hit_rate(c.cache_hit_rate);
  out->set_cache_capacity_bytes(c.cache_capacity_bytes);
  out->set_role(c.role);
  out->set_leader(c.leader);
  out->set_buffered_bytes(c.buffered_bytes);
  out->set_memory_budget_bytes(c.memory_budget_bytes);
  for (const RequestLatency& l : c.requests) {
    wire::LatencySummary* s = out->add_requests();
    s->set_kind(l.kind);
    s->set_count(l.count);
    s->set_p50_ms(l.p50_ms);
    s->set_p95_ms(l.p95_ms);
    s->set_p99_ms(l.p99_ms);
  }
}

template <typename M>
ServerCounters TakeCounters(const M& m) {
  ServerCounters c;
  c.connections_open = m.connections_open();
  c.connections_total = m.connections_total();
  c.bytes_in = m.bytes_in();
  c.bytes_out = m.bytes_out();
  c.cache_hit_rate = m.cache_hit_rate();
  c.cache_capacity_bytes = m.cache_capacity_bytes();
  c.role = m.role();
  c.leader = m.leader();
  c.buffered_bytes = m.buffered_bytes();
  c.memory_budget_bytes = m.memory_budget_bytes();
  for (const wire::LatencySummary& l : m.requests()) {
    c.requests.push_back({l.kind(), l.count(), l.p50_ms(), l.p95_ms(), l.p99_ms()});
  }
  std::sort(c.requests.begin(), c.requests.end(),
            [](const RequestLatency& a, const RequestLatency& b) { return a.kind < b.kind; });
  return c;
}

// A reply whose body is not the one the op answers with: a server out of step with us.
Status WrongReply(const RequestKind& k, const wire::Response& r) {
  return Status::Corruption(std::string(k.name) + ": the server answered with body " +
                            std::to_string(r.body_case()) + ", not its reply");
}

}  // namespace

void ToWire(const ServerCounters& c, wire::ServerCounters* out) { PutCounters(c, out); }
ServerCounters FromWire(const wire::ServerCounters& c) { return TakeCounters(c); }

// ---- The ops' pairs. Defaults first: the row's flag, no dataset.

namespace op {

#define HVDB_KIND(NAME, BODY)                                                        \
  const RequestKind& NAME::Kind() { return Row(wire::Request::BODY); }
#define HVDB_REPEATABLE_BY_ROW(NAME) \
  bool NAME::Repeatable(const In&) { return Kind().repeatable; }
#define HVDB_ON_DATASET(NAME) \
  std::string NAME::Dataset(const In& in) { return in.dataset; }

// list
HVDB_KIND(List, kList)
HVDB_REPEATABLE_BY_ROW(List)
std::string List::Dataset(const In&) { return ""; }
void List::Put(const In&, wire::Request* req) { req->mutable_list(); }
Result<List::In> List::Take(const wire::Request&) { return Empty{}; }
void List::PutReply(const Out& out, wire::Response* r) {
  wire::DatasetList* l = r->mutable_datasets();  // set even when there are none
  for (const auto& n : out) l->add_names(n);
}
Result<List::Out> List::TakeReply(const wire::Response& r) {
  if (!r.has_datasets()) return WrongReply(Kind(), r);
  return Out(r.datasets().names().begin(), r.datasets().names().end());
}

// create
HVDB_KIND(Create, kCreate)
HVDB_REPEATABLE_BY_ROW(Create)
std::string Create::Dataset(const In& in) { return in.name; }
void Create::Put(const In& in, wire::Request* req) { wire::ToWire(in, req->mutable_create()); }
Result<Create::In> Create::Take(const wire::Request& req) { return wire::FromWire(req.create()); }
void Create::PutReply(const Out& out, wire::Response* r) { wire::ToWire(out, r->mutable_info()); }
Result<Create::Out> Create::TakeReply(const wire::Response& r) {
  if (!r.has_info()) return WrongReply(Kind(), r);
  return wire::FromWire(r.info());
}

// drop
HVDB_KIND(Drop, kDrop)
HVDB_REPEATABLE_BY_ROW(Drop)
std::string Drop::Dataset(const In& in) { return in; }
void Drop::Put(const In& in, wire::Request* req) { req->mutable_drop()->set_name(in); }
Result<Drop::In> Drop::Take(const wire::Request& req) { return req.drop().name(); }
void Drop::PutReply(const Out&, wire::Response* r) { r->mutable_ack(); }
Result<Drop::Out> Drop::TakeReply(const wire::Response&) { return Empty{}; }

// describe
HVDB_KIND(Describe, kDescribe)
HVDB_REPEATABLE_BY_ROW(Describe)
std::string Describe::Dataset(const In& in) { return in; }
void Describe::Put(const In& in, wire::Request* req) { req->mutable_describe()->set_dataset(in); }
Result<Describe::In> Describe::Take(const wire::Request& req) { return req.describe().dataset(); }
void Describe::PutReply(const Out& out, wire::Response* r) {
  wire::ToWire(out, r->mutable_info());
}
Result<Describe::Out> Describe::TakeReply(const wire::Response& r) {
  if (!r.has_info()) return WrongReply(Kind(), r);
  return wire::FromWire(r.info());
}

// Replies that are a commit's result.
#define HVDB_COMMIT_REPLY(NAME)                                                 \
  void NAME::PutReply(const Out& out, wire::Response* r) {                      \
    wire::ToWire(out, r->mutable_commit());                                     \
  }                                                                             \
  Result<NAME::Out> NAME::TakeReply(const wire::Response& r) {                  \
    if (!r.has_commit()) return WrongReply(Kind(), r);                          \
    return wire::FromWire(r.commit());                                          \
  }

// edit
HVDB_KIND(Edit, kEdit)
HVDB_REPEATABLE_BY_ROW(Edit)
HVDB_ON_DATASET(Edit)
void Edit::Put(const In& in, wire::Request* req) {
  req->mutable_edit()->set_dataset(in.dataset);
  wire::ToWire(in.value, req->mutable_edit());
}
Result<Edit::In> Edit::Take(const wire::Request& req) {
  HVDB_ASSIGN_OR_RETURN(Transaction t, wire::FromWire(req.edit()));
  return In{req.edit().dataset(), std::move(t)};
}
HVDB_COMMIT_REPLY(Edit)

// revert
HVDB_KIND(Revert, kRevert)
HVDB_REPEATABLE_BY_ROW(Revert)
HVDB_ON_DATASET(Revert)
void Revert::Put(const In& in, wire::Request* req) {
  req->mutable_revert()->set_dataset(in.dataset);
  req->mutable_revert()->set_lsn(in.value);
}
Result<Revert::In> Revert::Take(const wire::Request& req) {
  return In{req.revert().dataset(), req.revert().lsn()};
}
HVDB_COMMIT_REPLY(Revert)

// stats
HVDB_KIND(Stats, kStats)
HVDB_REPEATABLE_BY_ROW(Stats)
std::string Stats::Dataset(const In& in) { return in; }
void Stats::Put(const In& in, wire::Request* req) { req->mutable_stats()->set_dataset(in); }
Result<Stats::In> Stats::Take(const wire::Request& req) { return req.stats().dataset(); }
void Stats::PutReply(const Out& out, wire::Response* r) {
  wire::StatsReply* s = r->mutable_stats();
  PutCounters(out.server, s);
  if (out.dataset) {
    s->set_last_lsn(out.dataset->last_lsn);
    wire::ToWire(out.dataset->stats, s->mutable_dataset());
  }
}
Result<Stats::Out> Stats::TakeReply(const wire::Response& r) {
  if (!r.has_stats()) return WrongReply(Kind(), r);
  Out out;
  out.server = TakeCounters(r.stats());
  if (r.stats().has_dataset()) {
    out.dataset = DatasetReport{wire::FromWire(r.stats().dataset()), r.stats().last_lsn()};
  }
  return out;
}

// server_stats
HVDB_KIND(ServerStats, kServerStats)
HVDB_REPEATABLE_BY_ROW(ServerStats)
std::string ServerStats::Dataset(const In&) { return ""; }
void ServerStats::Put(const In&, wire::Request* req) { req->mutable_server_stats(); }
Result<ServerStats::In> ServerStats::Take(const wire::Request&) { return Empty{}; }
void ServerStats::PutReply(const Out& out, wire::Response* r) { ToWire(out, r->mutable_server()); }
Result<ServerStats::Out> ServerStats::TakeReply(const wire::Response& r) {
  if (!r.has_server()) return WrongReply(Kind(), r);
  return FromWire(r.server());
}

// put_photo
HVDB_KIND(PutPhoto, kPutPhoto)
HVDB_REPEATABLE_BY_ROW(PutPhoto)
HVDB_ON_DATASET(PutPhoto)
void PutPhoto::Put(const In& in, wire::Request* req) {
  wire::PutPhoto* p = req->mutable_put_photo();
  p->set_dataset(in.dataset);
  p->set_frame(in.value.frame);
  wire::ToWire(in.value.photo, p);
}
Result<PutPhoto::In> PutPhoto::Take(const wire::Request& req) {
  HVDB_ASSIGN_OR_RETURN(Photo photo, wire::FromWire(req.put_photo()));
  return In{req.put_photo().dataset(), PhotoUpload{req.put_photo().frame(), std::move(photo)}};
}
void PutPhoto::PutReply(const Out&, wire::Response* r) { r->mutable_ack(); }
Result<PutPhoto::Out> PutPhoto::TakeReply(const wire::Response&) { return Empty{}; }

// The editing operators: their messages carry the dataset beside the value.
#define HVDB_EDIT_OP(NAME, FIELD)                                               \
  HVDB_KIND(NAME, k##NAME)                                                      \
  HVDB_ON_DATASET(NAME)                                                         \
  void NAME::Put(const In& in, wire::Request* req) {                            \
    req->mutable_##FIELD()->set_dataset(in.dataset);                            \
    wire::ToWire(in.value, req->mutable_##FIELD());                             \
  }                                                                             \
  Result<NAME::In> NAME::Take(const wire::Request& req) {                       \
    HVDB_ASSIGN_OR_RETURN(auto v, wire::FromWire(req.FIELD()));                 \
    return In{req.FIELD().dataset(), std::move(v)};                             \
  }

HVDB_EDIT_OP(Select, select)
HVDB_REPEATABLE_BY_ROW(Select)
void Select::PutReply(const Out& out, wire::Response* r) {
  wire::ToWire(out, r->mutable_selected());
}
Result<Select::Out> Select::TakeReply(const wire::Response& r) {
  if (!r.has_selected()) return WrongReply(Kind(), r);
  return wire::FromWire(r.selected());
}

HVDB_EDIT_OP(GraphCut, graph_cut)
HVDB_REPEATABLE_BY_ROW(GraphCut)
void GraphCut::PutReply(const Out& out, wire::Response* r) {
  wire::ToWire(out, r->mutable_graph_cut());
}
Result<GraphCut::Out> GraphCut::TakeReply(const wire::Response& r) {
  if (!r.has_graph_cut()) return WrongReply(Kind(), r);
  return wire::FromWire(r.graph_cut());
}

HVDB_EDIT_OP(Copy, copy)
// A copy only rewrites the clipboard: safe to repeat. A cut deletes: not.
bool Copy::Repeatable(const In& in) { return Kind().repeatable && !in.value.cut; }
void Copy::PutReply(const Out& out, wire::Response* r) { wire::ToWire(out, r->mutable_copied()); }
Result<Copy::Out> Copy::TakeReply(const wire::Response& r) {
  if (!r.has_copied()) return WrongReply(Kind(), r);
  return wire::FromWire(r.copied());
}

HVDB_EDIT_OP(Paste, paste)
HVDB_REPEATABLE_BY_ROW(Paste)
HVDB_COMMIT_REPLY(Paste)

HVDB_EDIT_OP(Composite, composite)
HVDB_REPEATABLE_BY_ROW(Composite)
HVDB_COMMIT_REPLY(Composite)

HVDB_EDIT_OP(ImportMedia, import_media)
HVDB_REPEATABLE_BY_ROW(ImportMedia)
HVDB_COMMIT_REPLY(ImportMedia)

// compact
HVDB_KIND(Compact, kCompact)
// Safe to repeat: frames compressed (or photos coded) already are left as they are.
HVDB_REPEATABLE_BY_ROW(Compact)
HVDB_ON_DATASET(Compact)
void Compact::Put(const In& in, wire::Request* req) {
  wire::CompactRequest* c = req->mutable_compact();
  c->set_dataset(in.dataset);
  c->set_first(in.value.first);
  c->set_last(in.value.last);
  c->set_photos(in.value.photos);
}
Result<Compact::In> Compact::Take(const wire::Request& req) {
  HVDB_ASSIGN_OR_RETURN(wire::CompactArgs a, wire::FromWire(req.compact()));
  return In{req.compact().dataset(), a};
}
void Compact::PutReply(const Out& out, wire::Response* r) {
  wire::ToWire(out, r->mutable_compacted());
}
Result<Compact::Out> Compact::TakeReply(const wire::Response& r) {
  if (!r.has_compacted()) return WrongReply(Kind(), r);
  return wire::FromWire(r.compacted());
}

// read_gaussians
HVDB_KIND(ReadGaussians, kReadGaussians)
HVDB_REPEATABLE_BY_ROW(ReadGaussians)
HVDB_ON_DATASET(ReadGaussians)
void ReadGaussians::Put(const In& in, wire::Request* req) {
  wire::ReadGaussians* r = req->mutable_read_gaussians();
  r->set_dataset(in.dataset);
  std::string* ids = r->mutable_ids();
  ids->resize(8 * in.value.size());
  for (size_t i = 0; i < in.value.size(); ++i) {
    EncodeLE<uint64_t>(reinterpret_cast<uint8_t*>(ids->data()) + 8 * i, in.value[i]);
  }
}
Result<ReadGaussians::In> ReadGaussians::Take(const wire::Request& req) {
  const std::string& b = req.read_gaussians().ids();
  if (b.size() % 8 != 0) {
    return Status::InvalidArgument("read_gaussians: ids hold " + std::to_string(b.size()) +
                                   " bytes, not a multiple of 8");
  }
  if (b.size() / 8 > kMaxGaussianReadIds) {
    return Status::InvalidArgument("read_gaussians: " + std::to_string(b.size() / 8) +
                                   " ids, at most " + std::to_string(kMaxGaussianReadIds) +
                                   " a request");
  }
  In in{req.read_gaussians().dataset(), std::vector<uint64_t>(b.size() / 8)};
  for (size_t i = 0; i < in.value.size(); ++i) {
    in.value[i] = DecodeLE<uint64_t>(reinterpret_cast<const uint8_t*>(b.data()) + 8 * i);
  }
  return in;
}
void ReadGaussians::PutReply(const Out& out, wire::Response* r) {
  wire::GaussianRecords* g = r->mutable_gaussians();
  wire::EncodeGaussians(out.records, 0, out.records.size(), g);
  std::string* found = g->mutable_found();
  found->assign((out.found.size() + 7) / 8, '\0');
  for (size_t i = 0; i < out.found.size(); ++i) {
    if (out.found[i]) (*found)[i / 8] = static_cast<char>((*found)[i / 8] | (1 << (i % 8)));
  }
}
Result<ReadGaussians::Out> ReadGaussians::TakeReply(const wire::Response& r) {
  if (!r.has_gaussians()) return WrongReply(Kind(), r);
  Out out;
  HVDB_RETURN_IF_ERROR(wire::DecodeGaussians(r.gaussians(), &out.records));
  const size_t n = r.gaussians().count();
  if (r.gaussians().found().size() != (n + 7) / 8) {
    return Status::InvalidArgument("read_gaussians reply: found bitmap of the wrong size");
  }
  out.found.resize(n);
  for (size_t i = 0; i < n; ++i) out.found[i] = (r.gaussians().found()[i / 8] >> (i % 8)) & 1;
  return out;
}

#undef HVDB_EDIT_OP
#undef HVDB_COMMIT_REPLY
#undef HVDB_ON_DATASET
#undef HVDB_REPEATABLE_BY_ROW
#undef HVDB_KIND

}  // namespace op



}  // namespace hvdb::service
