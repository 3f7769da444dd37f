#include "protocol/ws_codec.h"

#include <google/protobuf/util/json_util.h>

#include <utility>
#include <vector>

#include "protocol/hvdb.pb.h"

namespace hvdb::wire {

namespace {

size_t Align8(size_t n) { return (n + 7) & ~size_t{7}; }

struct Section {
  std::string name;
  std::string bytes;
};

void Take(const char* name, std::string* field, std::vector<Section>* out) {
  if (field->empty()) return;
  out->push_back({name, std::move(*field)});
  field->clear();
}

// The bulk bytes of a batch or render reply, moved out of *r in field order.
std::vector<Section> TakeBulk(Response* r) {
  std::vector<Section> s;
  if (r->has_batch()) {
    PointBatch* b = r->mutable_batch();
    if (b->has_columns()) {
      PointColumns* c = b->mutable_columns();
      Take("id", c->mutable_id(), &s);
      Take("position", c->mutable_position(), &s);
      Take("frame", c->mutable_frame(), &s);
      Take("color", c->mutable_color(), &s);
      Take("covariance", c->mutable_covariance(), &s);
      Take("normal", c->mutable_normal(), &s);
      Take("label", c->mutable_label(), &s);
      Take("camera", c->mutable_camera(), &s);
      Take("flags", c->mutable_flags(), &s);
    }
    Take("draco", b->mutable_draco(), &s);
    Take("hvdb7", b->mutable_hvdb7(), &s);
  }
  if (r->has_render()) {
    Take("png", r->mutable_render()->mutable_png(), &s);
    Take("exr", r->mutable_render()->mutable_exr(), &s);
    Take("video", r->mutable_render()->mutable_video(), &s);
  }
  return s;
}

}  // namespace

std::string ToJson(const google::protobuf::Message& m) {
  google::protobuf::util::JsonPrintOptions o;
  o.always_print_primitive_fields = true;
  o.preserve_proto_field_names = true;
  std::string out;
  auto st = google::protobuf::util::MessageToJsonString(m, &out, o);
  if (!st.ok()) {  // e.g. a string field that is not UTF-8: the client still gets an answer
    const auto* r = dynamic_cast<const Response*>(&m);
    Response err;
    err.set_id(r != nullptr ? r->id() : 0);
    err.mutable_error()->set_code(INTERNAL);
    err.mutable_error()->set_message("the response cannot be written as JSON");
    out.clear();
    (void)google::protobuf::util::MessageToJsonString(err, &out, o);  // ASCII only: cannot fail
  }
  return out;
}

Status DecodeWsMessage(bool text, std::string_view data, google::protobuf::Message* out) {
  out->Clear();
  if (!text) {
    if (!out->ParseFromArray(data.data(), static_cast<int>(data.size()))) {
      return Status::InvalidArgument("binary message is not a valid " + out->GetTypeName() +
                                     " (serialized protobuf)");
    }
    return Status::OK();
  }
  google::protobuf::util::JsonParseOptions o;
  o.ignore_unknown_fields = false;  // a misspelt field is an error, not a silent default
  auto st = google::protobuf::util::JsonStringToMessage(
      google::protobuf::StringPiece(data.data(), data.size()), out, o);
  if (!st.ok()) {
    out->Clear();
    return Status::InvalidArgument("text message is not a " + out->GetTypeName() +
                                   " in JSON: " + std::string(st.message()));
  }
  return Status::OK();
}

WsMessage EncodeWsMessage(const google::protobuf::Message& m, size_t records_bytes) {
  const auto* resp = dynamic_cast<const Response*>(&m);
  if (resp == nullptr || (!resp->has_batch() && !resp->has_render())) {
    return WsMessage{true, ToJson(m), {}};
  }
  Response r = *resp;
  std::vector<Section> sections = TakeBulk(&r);
  const std::string body = ToJson(r);
  // The sections' offsets depend on the header's length, which depends on the offsets'
  // digits: iterate until the padded header length is stable (two or three rounds).
  std::string json;
  size_t base = Align8(4 + body.size() + 64);
  for (int round = 0; round < 16; ++round) {
    json = "{\"response\":" + body + ",\"payload\":[";
    size_t at = base;
    bool first = true;
    auto add = [&](const std::string& name, size_t len) {
      if (!first) json += ',';
      first = false;
      json += "{\"field\":\"" + name + "\",\"offset\":" + std::to_string(at) +
              ",\"length\":" + std::to_string(len) + "}";
      at = Align8(at + len);
    };
    if (records_bytes > 0) add("records", records_bytes);
    for (const Section& s : sections) add(s.name, s.bytes.size());
    json += "]}";
    size_t need = Align8(4 + json.size());
    if (need == base) break;
    base = need;
  }
  WsMessage out;
  out.text = false;
  out.head.reserve(base);
  const auto j = static_cast<uint32_t>(json.size());
  for (int i = 0; i < 4; ++i) out.head.push_back(static_cast<char>((j >> (8 * i)) & 0xff));
  out.head += json;
  out.head.resize(base, '\0');
  // Records are a whole number of 64-byte records, so the sections after them stay aligned.
  for (const Section& s : sections) {
    out.tail += s.bytes;
    out.tail.resize(Align8(out.tail.size()), '\0');
  }
  return out;
}

}  // namespace hvdb::wire
