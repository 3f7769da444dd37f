// The executor's side of the request table (requests.h): each unary op's call on the Service,
// and ExecuteUnary, which every transport's unary request goes through.
#include "service/requests.h"
#include "service/service.h"

namespace hvdb::service {

namespace op {

Result<List::Out> List::Run(Service& x, const In&) { return x.ListDatasets(); }
Result<Create::Out> Create::Run(Service& x, const In& in) { return x.CreateDataset(in); }
Result<Drop::Out> Drop::Run(Service& x, const In& in) {
  HVDB_RETURN_IF_ERROR(x.DropDataset(in));
  return Empty{};
}
Result<Describe::Out> Describe::Run(Service& x, const In& in) { return x.Describe(in); }
Result<ReadGaussians::Out> ReadGaussians::Run(Service& x, const In& in) {
  return x.ReadGaussians(in.dataset, in.value);
}
Result<Edit::Out> Edit::Run(Service& x, const In& in) { return x.Commit(in.dataset, in.value); }
Result<Revert::Out> Revert::Run(Service& x, const In& in) {
  return x.Revert(in.dataset, in.value);
}
Result<Stats::Out> Stats::Run(Service& x, const In& in) {
  Out out;
  out.server = x.Counters();
  if (!in.empty()) {
    HVDB_ASSIGN_OR_RETURN(DatasetReport d, x.Stats(in));
    out.dataset = d;
  }
  return out;
}
Result<ServerStats::Out> ServerStats::Run(Service& x, const In&) { return x.Counters(); }
Result<PutPhoto::Out> PutPhoto::Run(Service& x, const In& in) {
  HVDB_RETURN_IF_ERROR(x.PutPhoto(in.dataset, in.value.frame, in.value.photo));
  return Empty{};
}
Result<Select::Out> Select::Run(Service& x, const In& in) {
  return x.Select(in.dataset, in.value);
}
Result<GraphCut::Out> GraphCut::Run(Service& x, const In& in) {
  return x.GraphCut(in.dataset, in.value);
}
Result<Copy::Out> Copy::Run(Service& x, const In& in) { return x.Copy(in.dataset, in.value); }
Result<Paste::Out> Paste::Run(Service& x, const In& in) { return x.Paste(in.dataset, in.value); }
Result<Composite::Out> Composite::Run(Service& x, const In& in) {
  return x.Composite(in.dataset, in.value);
}
Result<ImportMedia::Out> ImportMedia::Run(Service& x, const In& in) {
  return x.ImportMedia(in.dataset, in.value);
}
Result<Compact::Out> Compact::Run(Service& x, const In& in) {
  return x.Compact(in.dataset, in.value.first, in.value.last, in.value.photos);
}

}  // namespace op

namespace {

template <typename Op>
wire::Response Serve(Service& x, const wire::Request& req) {
  Result<typename Op::In> in = Op::Take(req);
  if (!in.ok()) return ErrorResponse(req.id(), in.status());
  Result<typename Op::Out> out = Op::Run(x, *in);
  if (!out.ok()) return ErrorResponse(req.id(), out.status());
  wire::Response r;
  r.set_id(req.id());
  Op::PutReply(*out, &r);
  return r;
}

// Rows whose flow is not unary have no op: their branch is never instantiated.
template <Flow F, typename Op>
wire::Response Dispatch(Service& x, const wire::Request& req) {
  if constexpr (F == Flow::kUnary) {
    return Serve<Op>(x, req);
  } else {
    return ErrorResponse(req.id(), Status::InvalidArgument("request: not a unary request"),
                         wire::MALFORMED);
  }
}

}  // namespace

namespace op {
// Names for the rows that have no op, so that the table's list expands for every row.
struct Ping;
struct Cancel;
struct Release;
struct Query;
struct Ingest;
struct Render;
struct Watch;
}  // namespace op

wire::Response ExecuteUnary(Service& x, const wire::Request& req) {
  switch (req.body_case()) {
#define HVDB_CASE(OP, BODY, NAME, WRITES, FLOW, REPEATABLE, TOO_LARGE) \
  case wire::Request::BODY:                                            \
    return Dispatch<Flow::FLOW, op::OP>(x, req);
    HVDB_REQUESTS(HVDB_CASE)
#undef HVDB_CASE
    default:
      return ErrorResponse(req.id(), Status::InvalidArgument("request: not a unary request"),
                           wire::MALFORMED);
  }
}

}  // namespace hvdb::service
