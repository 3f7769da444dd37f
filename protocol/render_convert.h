// ToWire / FromWire pairs for the render job's request and reply values (render/request.h) and
// the wire's Render and RenderReply messages. Each pair round-trips
// (tests/protocol/render_convert_test.cc). As in convert.h, FromWire decodes the shape of a
// message only — known renderer, format and mode values; 4 background and highlight_color
// values, 3 shadow_light values, or none; a view of one of its three kinds, a look-at's 3 eye
// and target (and 0 or 3 up) values, a camera's intrinsics — naming the field as the render
// job names it ("render.background: needs 4 values ..."); whether the values make sense is
// RenderJob::Create's to say, for embedded and remote callers alike.
#ifndef HVDB_PROTOCOL_RENDER_CONVERT_H_
#define HVDB_PROTOCOL_RENDER_CONVERT_H_

#include <string>

#include "protocol/wire.h"
#include "render/request.h"

namespace hvdb::wire {

void ToWire(const render::RenderRequest& r, wire::Render* out);
Result<render::RenderRequest> FromWire(const wire::Render& r);

// A view of a request; `field` ("render.view", "render.path[3]") names it in errors.
void ToWire(const render::View& v, wire::View* out);
Result<render::View> FromWire(const wire::View& v, const std::string& field);

// The reply's bytes are moved from an rvalue (hvdb-server sends each image once).
void ToWire(const render::RenderReply& r, wire::RenderReply* out);
void ToWire(render::RenderReply&& r, wire::RenderReply* out);
render::RenderReply FromWire(const wire::RenderReply& r);

}  // namespace hvdb::wire

#endif  // HVDB_PROTOCOL_RENDER_CONVERT_H_
