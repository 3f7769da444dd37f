#include "protocol/render_convert.h"

#include <utility>
#include <variant>

namespace hvdb::wire {

namespace {

Status Invalid(const std::string& field, const std::string& why) {
  return Status::InvalidArgument(field + ": " + why);
}

// Prefixes a check's message with the request field it concerns.
Status InField(const std::string& field, const Status& st) {
  if (st.ok()) return st;
  return Status(st.code(), field + ": " + st.message());
}

template <typename T, size_t N, typename Repeated>
std::array<T, N> ArrayOf(const Repeated& v) {
  std::array<T, N> a{};
  for (size_t i = 0; i < N; ++i) a[i] = v[static_cast<int>(i)];
  return a;
}

}  // namespace

void ToWire(const render::View& v, wire::View* out) {
  if (const auto* c = std::get_if<CameraInfo>(&v)) {
    ToWire(*c, out->mutable_camera());
  } else if (const auto* d = std::get_if<render::DatasetCameraView>(&v)) {
    out->set_dataset_camera(d->id);
  } else {
    const auto& l = std::get<render::LookAtView>(v);
    wire::LookAt* o = out->mutable_look_at();
    for (double x : l.eye) o->add_eye(x);
    for (double x : l.target) o->add_target(x);
    if (l.up) {
      for (double x : *l.up) o->add_up(x);
    }
    o->set_fov_y_deg(l.fov_y_deg);
    o->set_width(l.width);
    o->set_height(l.height);
  }
}

Result<render::View> FromWire(const wire::View& v, const std::string& field) {
  switch (v.kind_case()) {
    case wire::View::kCamera: {
      Result<CameraInfo> c = FromWire(v.camera());
      if (!c.ok()) return InField(field, c.status());
      return render::View(std::move(c).value());
    }
    case wire::View::kLookAt: {
      const wire::LookAt& l = v.look_at();
      if (l.eye_size() != 3 || l.target_size() != 3) {
        return Invalid(field + ".look_at", "eye and target need 3 values each");
      }
      if (l.up_size() != 0 && l.up_size() != 3) {
        return Invalid(field + ".look_at.up", "needs 3 values (or none for 0 1 0)");
      }
      render::LookAtView o;
      o.eye = ArrayOf<double, 3>(l.eye());
      o.target = ArrayOf<double, 3>(l.target());
      if (l.up_size() == 3) o.up = ArrayOf<double, 3>(l.up());
      o.fov_y_deg = l.fov_y_deg();
      o.width = l.width();
      o.height = l.height();
      return render::View(o);
    }
    case wire::View::kDatasetCamera:
      return render::View(render::DatasetCameraView{v.dataset_camera()});
    default:
      return Invalid(field, "needs a camera, a look_at or a dataset_camera");
  }
}

void ToWire(const render::RenderRequest& r, wire::Render* out) {
  out->set_dataset(r.dataset);
  if (r.region) ToWire(*r.region, out->mutable_region());
  out->set_lod(r.lod);
  if (r.view) ToWire(*r.view, out->mutable_view());
  if (r.mode) {
    out->set_mode(*r.mode == render::Mode::kProbabilistic ? wire::RENDER_PROBABILISTIC
                  : *r.mode == render::Mode::kGaussian    ? wire::RENDER_GAUSSIAN
                                                          : wire::RENDER_VISIBILITY);
  }
  out->set_view_dependent(r.view_dependent);
  out->set_width(r.width);
  out->set_height(r.height);
  if (r.background) {
    for (float x : *r.background) out->add_background(x);
  }
  switch (r.renderer) {
    case render::RendererKind::kAuto: out->set_renderer(wire::RENDERER_AUTO); break;
    case render::RendererKind::kEgl: out->set_renderer(wire::RENDERER_EGL); break;
    case render::RendererKind::kCpu: out->set_renderer(wire::RENDERER_CPU); break;
  }
  out->set_depth_threshold(r.depth_threshold);
  out->set_cutoff_radius(r.cutoff_radius);
  switch (r.format) {
    case render::ImageFormat::kPng: out->set_format(wire::IMAGE_PNG); break;
    case render::ImageFormat::kExr: out->set_format(wire::IMAGE_EXR); break;
    case render::ImageFormat::kMp4: out->set_format(wire::IMAGE_MP4); break;
    case render::ImageFormat::kWebm: out->set_format(wire::IMAGE_WEBM); break;
  }
  for (const render::View& v : r.path) ToWire(v, out->add_path());
  for (uint32_t f : r.frames) out->add_frames(f);
  out->set_no_temporal_lod(r.no_temporal_lod);
  out->set_label_mask(r.label_mask);
  out->set_progressive(r.progressive);
  out->set_highlight_mask(r.highlight_mask);
  if (r.highlight_color) {
    for (float x : *r.highlight_color) out->add_highlight_color(x);
  }
  if (r.texture) out->set_texture(*r.texture);
  if (r.billboards) out->set_billboards(*r.billboards);
  if (r.shadow_light) {
    for (double x : *r.shadow_light) out->add_shadow_light(x);
  }
  out->set_shadow_directional(r.shadow_directional);
  out->set_shadow_casters(r.shadow_casters);
  out->set_shadow_strength(r.shadow_strength);
  out->set_shadow_map_size(r.shadow_map_size);
  out->set_video_fps(r.video_fps);
}

Result<render::RenderRequest> FromWire(const wire::Render& r) {
  render::RenderRequest out;
  out.dataset = r.dataset();
  switch (r.renderer()) {
    case wire::RENDERER_AUTO: out.renderer = render::RendererKind::kAuto; break;
    case wire::RENDERER_EGL: out.renderer = render::RendererKind::kEgl; break;
    case wire::RENDERER_CPU: out.renderer = render::RendererKind::kCpu; break;
    default: return Invalid("render.renderer", "unknown value " + std::to_string(r.renderer()));
  }
  switch (r.format()) {
    case wire::IMAGE_PNG: out.format = render::ImageFormat::kPng; break;
    case wire::IMAGE_EXR: out.format = render::ImageFormat::kExr; break;
    case wire::IMAGE_MP4: out.format = render::ImageFormat::kMp4; break;
    case wire::IMAGE_WEBM: out.format = render::ImageFormat::kWebm; break;
    default: return Invalid("render.format", "unknown value " + std::to_string(r.format()));
  }
  if (r.has_mode()) {
    switch (r.mode()) {
      case wire::RENDER_VISIBILITY: out.mode = render::Mode::kVisibility; break;
      case wire::RENDER_PROBABILISTIC: out.mode = render::Mode::kProbabilistic; break;
      case wire::RENDER_GAUSSIAN: out.mode = render::Mode::kGaussian; break;
      default: return Invalid("render.mode", "unknown value " + std::to_string(r.mode()));
    }
  }
  out.lod = r.lod();
  out.no_temporal_lod = r.no_temporal_lod();
  out.label_mask = r.label_mask();
  out.highlight_mask = r.highlight_mask();
  if (r.highlight_color_size() == 4) {
    out.highlight_color = ArrayOf<float, 4>(r.highlight_color());
  } else if (r.highlight_color_size() != 0) {
    return Invalid("render.highlight_color", "needs 4 values (sRGB RGBA in [0, 1]) or none");
  }
  if (r.background_size() == 4) {
    out.background = ArrayOf<float, 4>(r.background());
  } else if (r.background_size() != 0) {
    return Invalid("render.background", "needs 4 values (linear RGBA) or none");
  }
  out.depth_threshold = r.depth_threshold();
  out.cutoff_radius = r.cutoff_radius();
  out.width = r.width();
  out.height = r.height();
  out.view_dependent = r.view_dependent();
  if (r.shadow_light_size() == 3) {
    out.shadow_light = ArrayOf<double, 3>(r.shadow_light());
  } else if (r.shadow_light_size() != 0) {
    return Invalid("render.shadow_light", "needs 3 values (a position, or with "
                                          "shadow_directional a direction), or none for no shadows");
  }
  out.shadow_directional = r.shadow_directional();
  out.shadow_casters = r.shadow_casters();
  out.shadow_strength = r.shadow_strength();
  out.shadow_map_size = r.shadow_map_size();
  if (r.has_texture()) out.texture = r.texture();
  if (r.has_billboards()) out.billboards = r.billboards();
  out.progressive = r.progressive();
  out.video_fps = r.video_fps();
  if (r.has_view()) {
    HVDB_ASSIGN_OR_RETURN(render::View v, FromWire(r.view(), "render.view"));
    out.view = std::move(v);
  }
  out.path.reserve(static_cast<size_t>(r.path_size()));
  for (int i = 0; i < r.path_size(); ++i) {
    HVDB_ASSIGN_OR_RETURN(render::View v,
                          FromWire(r.path(i), "render.path[" + std::to_string(i) + "]"));
    out.path.push_back(std::move(v));
  }
  out.frames.assign(r.frames().begin(), r.frames().end());
  if (r.has_region()) {
    HVDB_ASSIGN_OR_RETURN(hvdb::Region region, FromWire(r.region()));
    out.region = std::move(region);
  }
  return out;
}

void ToWire(const render::RenderReply& r, wire::RenderReply* out) {
  render::RenderReply copy = r;
  ToWire(std::move(copy), out);
}

void ToWire(render::RenderReply&& r, wire::RenderReply* out) {
  if (!r.png.empty()) out->set_png(std::move(r.png));
  if (!r.exr.empty()) out->set_exr(std::move(r.exr));
  if (!r.video.empty()) out->set_video(std::move(r.video));
  out->set_video_codec(std::move(r.video_codec));
  out->set_width(r.width);
  out->set_height(r.height);
  out->set_renderer_used(std::move(r.renderer_used));
  out->set_renderer_choice(std::move(r.renderer_choice));
  out->set_fallback(r.fallback);
  out->set_points(r.points);
  out->set_render_ms(r.render_ms);
  out->set_index(r.index);
  out->set_images(r.images);
  out->set_last(r.last);
  out->set_preview(r.preview);
  out->set_lod(r.lod);
  out->set_mode_used(std::move(r.mode_used));
  out->set_mode_choice(std::move(r.mode_choice));
}

render::RenderReply FromWire(const wire::RenderReply& r) {
  render::RenderReply out;
  out.png = r.png();
  out.exr = r.exr();
  out.video = r.video();
  out.video_codec = r.video_codec();
  out.width = r.width();
  out.height = r.height();
  out.renderer_used = r.renderer_used();
  out.renderer_choice = r.renderer_choice();
  out.fallback = r.fallback();
  out.points = r.points();
  out.render_ms = r.render_ms();
  out.index = r.index();
  out.images = r.images();
  out.last = r.last();
  out.preview = r.preview();
  out.lod = r.lod();
  out.mode_used = r.mode_used();
  out.mode_choice = r.mode_choice();
  return out;
}

}  // namespace hvdb::wire
