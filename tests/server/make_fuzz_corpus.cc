// Writes the seed corpus of frame_decoder_fuzz (tests/server/fuzz_corpus/): one valid session
// per request kind, and server answers with point batches (records in an attachment, in a ring
// slot, columns). Run by hand when the protocol changes: make_fuzz_corpus DIR.
#include <fstream>
#include <string>

#include "protocol/wire.h"

int main(int argc, char** argv) {
  if (argc != 2) return 2;
  using namespace hvdb;
  const std::string dir = argv[1];
  wire::Hello hello;
  hello.set_protocol_version(wire::kProtocolVersion);
  hello.set_token("tok");
  const std::string head = wire::Frame(hello);
  auto write = [&](const std::string& name, const wire::Request& r) {
    std::ofstream(dir + "/" + name, std::ios::binary) << head << wire::Frame(r);
  };
  wire::Request r;
  r.set_id(1);
  r.mutable_ping()->set_payload("x");
  write("ping", r);
  r.Clear();
  r.set_id(2);
  auto* q = r.mutable_query();
  q->set_dataset("d");
  Slice s;
  s.normal = {0.1, 0.2, 0.3, 0.9};
  s.thickness = 0.1;
  Window clip;
  clip.hi = {1, 1, 1, 1};
  s.clip = clip;
  wire::ToWire(Region(s), q->mutable_region());
  q->set_lod(2);
  q->set_progressive(true);
  write("query_slice", r);
  r.Clear();
  r.set_id(3);
  wire::ToWire(Region(clip), r.mutable_query()->mutable_region());
  write("query_window", r);
  r.Clear();
  r.set_id(4);
  Transaction t;
  Point p;
  p.id = 5;
  p.x = 1;
  t.Insert({p, p});
  t.Delete(5, 0, {1, 0, 0});
  Selection sel;
  sel.region = clip;
  sel.ids = {{0, 5}};
  t.DeleteSelection(sel);
  Affine4 a;
  a.c = {1, 0, 0, 0.1};
  t.Transform(sel, a);
  t.SetLabel(sel, 4, true);
  r.mutable_edit()->set_dataset("d");
  wire::ToWire(t, r.mutable_edit());
  write("edit", r);
  r.Clear();
  r.set_id(5);
  r.mutable_ingest()->set_dataset("d");
  Point pts[3] = {p, p, p};
  wire::EncodeColumns(pts, r.mutable_ingest()->mutable_points());
  r.mutable_ingest()->set_last(true);
  write("ingest", r);
  r.Clear();
  r.set_id(6);
  auto* c = r.mutable_create();
  c->set_name("d");
  c->set_fps(30);
  wire::ToWire(CameraInfo{}, c->add_cameras());
  write("create", r);
  r.Clear();
  r.set_id(7);
  r.mutable_release()->add_slots(2);
  write("release", r);
  r.Clear();
  r.set_id(8);
  r.mutable_watch()->set_dataset("d");
  r.mutable_watch()->set_from_lsn(3);
  write("watch", r);
  // The client's side: responses with batches.
  wire::Response resp;
  resp.set_id(2);
  auto* b = resp.mutable_batch();
  b->set_encoding(wire::RECORDS);
  b->set_record_count(3);
  std::string recs(3 * kPointRecordSize, '\0');
  EncodePoints(pts, reinterpret_cast<uint8_t*>(recs.data()));
  wire::Response done;
  done.set_id(2);
  done.mutable_done()->set_points(3);
  std::ofstream(dir + "/response_records", std::ios::binary)
      << wire::FrameHead(resp, static_cast<uint32_t>(recs.size())) << recs << wire::Frame(done);
  b->set_shm_slot(1);
  std::ofstream(dir + "/response_shm", std::ios::binary) << wire::Frame(resp) << wire::Frame(done);
  b->Clear();
  b->set_encoding(wire::COLUMNS);
  wire::EncodeColumns(pts, b->mutable_columns());
  std::ofstream(dir + "/response_columns", std::ios::binary) << wire::Frame(resp);
  wire::Response ev;
  ev.set_id(8);
  ev.mutable_event()->set_dataset("d");
  ev.mutable_event()->set_lsn(4);
  ev.mutable_event()->set_kind(wire::WATCH_BULK);
  ev.mutable_event()->add_frames(7);
  ev.mutable_event()->set_points(75012);
  std::ofstream(dir + "/response_watch", std::ios::binary) << wire::Frame(ev);
  return 0;
}
