#include "server/requests.h"

#include <optional>

#include "edit/operators.h"
#include "protocol/convert.h"
#include "service/service.h"

namespace hvdb::server {

const char* KindOf(const wire::Request& r) {
  switch (r.body_case()) {
    case wire::Request::kPing: return "ping";
    case wire::Request::kList: return "list";
    case wire::Request::kCreate: return "create";
    case wire::Request::kDrop: return "drop";
    case wire::Request::kDescribe: return "describe";
    case wire::Request::kQuery: return "query";
    case wire::Request::kCancel: return "cancel";
    case wire::Request::kEdit: return "edit";
    case wire::Request::kRevert: return "revert";
    case wire::Request::kIngest: return "ingest";
    case wire::Request::kStats: return "stats";
    case wire::Request::kRender: return "render";
    case wire::Request::kPutPhoto: return "put_photo";
    case wire::Request::kSelect: return "select";
    case wire::Request::kGraphCut: return "graph_cut";
    case wire::Request::kCopy: return "copy";
    case wire::Request::kPaste: return "paste";
    case wire::Request::kComposite: return "composite";
    case wire::Request::kImportMedia: return "import_media";
    case wire::Request::kRelease: return "release";
    case wire::Request::kWatch: return "watch";
    case wire::Request::kCompact: return "compact";
    default: return "unknown";
  }
}

bool Writes(const wire::Request& r) {
  switch (r.body_case()) {
    case wire::Request::kCreate:
    case wire::Request::kDrop:
    case wire::Request::kEdit:
    case wire::Request::kRevert:
    case wire::Request::kIngest:
    case wire::Request::kPutPhoto:
    case wire::Request::kSelect:
    case wire::Request::kGraphCut:
    case wire::Request::kCopy:
    case wire::Request::kPaste:
    case wire::Request::kComposite:
    case wire::Request::kImportMedia:
    case wire::Request::kCompact: return true;
    default: return false;
  }
}

wire::Response ErrorResponse(uint64_t id, const Status& st, wire::ErrorCode code) {
  wire::Response r;
  r.set_id(id);
  wire::ToWire(st, r.mutable_error());
  if (code == wire::ERROR_UNSPECIFIED && service::IsUnknownDataset(st)) code = wire::UNKNOWN_DATASET;
  if (code != wire::ERROR_UNSPECIFIED) r.mutable_error()->set_code(code);
  return r;
}

bool IsUnary(const wire::Request& r) {
  switch (r.body_case()) {
    case wire::Request::kList:
    case wire::Request::kCreate:
    case wire::Request::kDrop:
    case wire::Request::kDescribe:
    case wire::Request::kEdit:
    case wire::Request::kRevert:
    case wire::Request::kPutPhoto:
    case wire::Request::kSelect:
    case wire::Request::kGraphCut:
    case wire::Request::kCopy:
    case wire::Request::kPaste:
    case wire::Request::kComposite:
    case wire::Request::kImportMedia:
    case wire::Request::kCompact: return true;
    default: return false;
  }
}

namespace {

// Decodes the body with `decode`, runs `run` on the executor and encodes its value with `encode`;
// an error of either step becomes the error response.
template <typename In, typename Decode, typename Run, typename Encode>
wire::Response Serve(uint64_t id, const In& in, Decode decode, Run run, Encode encode) {
  auto req = decode(in);
  if (!req.ok()) return ErrorResponse(id, req.status());
  auto out = run(*req);
  if (!out.ok()) return ErrorResponse(id, out.status());
  wire::Response r;
  r.set_id(id);
  encode(*out, &r);
  return r;
}

wire::Response Ack(uint64_t id, const Status& st) {
  if (!st.ok()) return ErrorResponse(id, st);
  wire::Response r;
  r.set_id(id);
  r.mutable_ack();
  return r;
}

template <typename T>
Result<T> Decoded(const T& v) { return v; }

void EncodeCommit(const CommitInfo& c, wire::Response* r) { wire::ToWire(c, r->mutable_commit()); }

}  // namespace

wire::Response Execute(Server* s, uint64_t id, const wire::Request& req) {
  service::Service& x = s->service();
  switch (req.body_case()) {
    case wire::Request::kList: {
      wire::Response r;
      r.set_id(id);
      for (const auto& n : x.ListDatasets()) r.mutable_datasets()->add_names(n);
      return r;
    }
    case wire::Request::kCreate:
      return Serve(id, req.create(), [](const auto& c) { return wire::FromWire(c); },
                   [&](const DatasetInfo& info) { return x.CreateDataset(info); },
                   [](const DatasetInfo& info, wire::Response* r) { wire::ToWire(info, r->mutable_info()); });
    case wire::Request::kDrop:
      return Ack(id, x.DropDataset(req.drop().name()));
    case wire::Request::kDescribe:
      return Serve(id, req.describe().dataset(), Decoded<std::string>,
                   [&](const std::string& name) { return x.Describe(name); },
                   [](const DatasetInfo& info, wire::Response* r) { wire::ToWire(info, r->mutable_info()); });
    case wire::Request::kEdit:
      return Serve(id, req.edit(), [](const auto& e) { return wire::FromWire(e); },
                   [&](const Transaction& t) { return x.Commit(req.edit().dataset(), t); }, EncodeCommit);
    case wire::Request::kRevert:
      return Serve(id, req.revert().lsn(), Decoded<uint64_t>,
                   [&](uint64_t lsn) { return x.Revert(req.revert().dataset(), lsn); }, EncodeCommit);
    case wire::Request::kPutPhoto: {
      const wire::PutPhoto& pp = req.put_photo();
      auto photo = wire::FromWire(pp);
      if (!photo.ok()) return ErrorResponse(id, photo.status());
      return Ack(id, x.PutPhoto(pp.dataset(), pp.frame(), *photo));
    }
    case wire::Request::kSelect:
      return Serve(id, req.select(), [](const auto& q) { return wire::FromWire(q); },
                   [&](const edit::SelectRequest& q) { return x.Select(req.select().dataset(), q); },
                   [](const edit::SelectResult& v, wire::Response* r) { wire::ToWire(v, r->mutable_selected()); });
    case wire::Request::kGraphCut:
      return Serve(id, req.graph_cut(), [](const auto& q) { return wire::FromWire(q); },
                   [&](const edit::GraphCutRequest& q) { return x.GraphCut(req.graph_cut().dataset(), q); },
                   [](const edit::GraphCutReply& v, wire::Response* r) { wire::ToWire(v, r->mutable_graph_cut()); });
    case wire::Request::kCopy:
      return Serve(id, req.copy(), [](const auto& q) { return wire::FromWire(q); },
                   [&](const edit::CopyRequest& q) { return x.Copy(req.copy().dataset(), q); },
                   [](const edit::CopyResult& v, wire::Response* r) { wire::ToWire(v, r->mutable_copied()); });
    case wire::Request::kPaste:
      return Serve(id, req.paste(), [](const auto& q) { return wire::FromWire(q); },
                   [&](const edit::PasteRequest& q) { return x.Paste(req.paste().dataset(), q); }, EncodeCommit);
    case wire::Request::kComposite:
      return Serve(id, req.composite(), [](const auto& q) { return wire::FromWire(q); },
                   [&](const edit::CompositeRequest& q) { return x.Composite(req.composite().dataset(), q); },
                   EncodeCommit);
    case wire::Request::kImportMedia:
      return Serve(id, req.import_media(), [](const auto& q) { return wire::FromWire(q); },
                   [&](const media::ImportRequest& q) {
                     return x.ImportMedia(req.import_media().dataset(), q);
                   },
                   EncodeCommit);
    case wire::Request::kCompact:
      return Serve(id, req.compact(), [](const auto& c) { return wire::FromWire(c); },
                   [&](const wire::CompactArgs& a) {
                     return x.Compact(req.compact().dataset(), a.first, a.last, a.photos);
                   },
                   [](const CompactInfo& c, wire::Response* r) { wire::ToWire(c, r->mutable_compacted()); });
    default:
      return ErrorResponse(id, Status::InvalidArgument("request: not a unary request"), wire::MALFORMED);
  }
}

}  // namespace hvdb::server
