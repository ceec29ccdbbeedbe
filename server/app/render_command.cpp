// `octoscope render INPUT|CACHE --out FILE.png|.jpg`: renders one image of a scan (octree built
// in RAM or in --cache DIR) or of an octree cache directory with the OpenCL renderer: a 3-D view
// (VolumeRenderer), optionally with slice planes drawn in (DrawSlicePlanes), or an axis-aligned
// slice (--slice, SliceRenderer).
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "app/commands.h"
#include "app/octree_loading.h"
#include "app/volume_options.h"
#include "dataset/cache_setup.h"
#include "dataset/display_defaults.h"
#include "encode/image_encoder.h"
#include "io/open_volume.h"
#include "protocol/render_json.h"
#include "protocol/render_report.h"
#include "render/bilinear_upsample.h"
#include "render/camera.h"
#include "render/device.h"
#include "render/device_octree.h"
#include "render/program_cache.h"
#include "render/reference_renderer.h"
#include "render/render_params.h"
#include "render/slice_overlay.h"
#include "render/slice_renderer.h"
#include "render/volume_renderer.h"
#include "util/file_reading.h"
#include "util/strings.h"

namespace octoscope::app {
namespace {

namespace fs = std::filesystem;

constexpr const char* kCommand = "octoscope render";
// Full frames are repeated until one requests nothing, at most this many.
constexpr int kMaxFullFrames = 64;

int Usage(const std::string& message, const Flags& flags) {
  std::fprintf(stderr, "%s: %s\n\n%s", kCommand, message.c_str(), flags.Help().c_str());
  return kExitUsage;
}

int Fail(const std::string& input, const Status& status) {
  return ReportBadInput(kCommand, input, status);
}

double MsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
      .count();
}

// "WxH" with both in [1, kMaxImageSize].
Result<std::pair<int, int>> ParseSize(const std::string& text) {
  const size_t x = text.find_first_of("xX");
  std::optional<int64_t> w, h;
  if (x != std::string::npos) {
    w = ParseInt64(std::string_view(text).substr(0, x));
    h = ParseInt64(std::string_view(text).substr(x + 1));
  }
  if (!w || !h || *w < 1 || *h < 1 || *w > render::kMaxImageSize || *h > render::kMaxImageSize) {
    return InvalidArgumentError("--size: expected WxH with each in 1.." +
                                std::to_string(render::kMaxImageSize) + ", got '" +
                                Printable(text) + "'");
  }
  return std::make_pair(static_cast<int>(*w), static_cast<int>(*h));
}

Status WriteBytes(const fs::path& path, const std::vector<uint8_t>& bytes) {
  const fs::path tmp = path.string() + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(bytes.data()),
              static_cast<std::streamsize>(bytes.size()));
    out.close();
    if (!out) {
      std::error_code ec;
      fs::remove(tmp, ec);
      return IoError(path.string() + ": cannot write the image");
    }
  }
  // A reader never sees a half-written image under the final name.
  std::error_code ec;
  fs::rename(tmp, path, ec);
  if (ec) return IoError(path.string() + ": cannot write the image: " + ec.message());
  return Status::Ok();
}

// One "AXIS[@POSITION_UM]" item of --slice or --slice-planes.
struct AxisPosition {
  int axis = 2;                       // 0 = x, 1 = y, 2 = z.
  std::optional<double> position_um;  // Unset: the volume's centre along the axis.
};

constexpr std::array<const char*, 3> kAxisNames = {"x", "y", "z"};
// Slice-plane line colours by axis: x red, y green, z blue.
constexpr std::array<std::array<double, 3>, 3> kPlaneColours = {{{1, 0, 0}, {0, 1, 0}, {0, 0, 1}}};

// "x", "y" or "z", optionally followed by "@" and a finite position in µm.
Result<AxisPosition> ParseAxisPosition(std::string_view text, const std::string& flag) {
  const auto bad = [&] {
    return InvalidArgumentError(flag + ": expected AXIS[@POSITION_UM] with AXIS x, y or z, got '" +
                                Printable(text) + "'");
  };
  const size_t at = text.find('@');
  const std::string_view axis_text = text.substr(0, at);
  AxisPosition out;
  if (axis_text == "x") {
    out.axis = 0;
  } else if (axis_text == "y") {
    out.axis = 1;
  } else if (axis_text == "z") {
    out.axis = 2;
  } else {
    return bad();
  }
  if (at != std::string_view::npos) {
    const std::optional<double> position = ParseDouble(text.substr(at + 1));
    // Also rejects "nan" and "inf", which from_chars accepts.
    if (!position || !std::isfinite(*position)) return bad();
    out.position_um = *position;
  }
  return out;
}

// A comma-separated, non-empty list of AXIS[@POSITION_UM] items.
Result<std::vector<AxisPosition>> ParseSlicePlanes(std::string_view text) {
  std::vector<AxisPosition> planes;
  size_t begin = 0;
  while (true) {
    const size_t comma = text.find(',', begin);
    OCTO_ASSIGN_OR_RETURN(AxisPosition plane,
                          ParseAxisPosition(text.substr(begin, comma - begin), "--slice-planes"));
    planes.push_back(plane);
    if (comma == std::string_view::npos) break;
    begin = comma + 1;
  }
  return planes;
}

// The item's position, or the centre of the volume box along its axis.
double PositionOrCentre(const AxisPosition& item, const render::Box3& bounds) {
  return item.position_um.value_or(bounds.Center()[item.axis]);
}

struct RenderOutcome {
  render::RenderImage image;
  render::FrameStats stats;
  double ms_last_frame = 0;     // Full frames: the last frame's wall time,
  double cpu_s_last_frame = 0;  // and its process CPU time (every thread: std::clock).
};

// Full frames until one requests nothing (everything it needs is resident) or `max_frames`.
Result<RenderOutcome> RenderFullFrames(render::VolumeRenderer& renderer,
                                       const render::Camera& camera,
                                       const render::RenderParams& params,
                                       const render::FrameOptions& options, int max_frames) {
  RenderOutcome out;
  for (int frame = 0; frame < max_frames; ++frame) {
    render::FrameStats s;
    const auto wall_start = std::chrono::steady_clock::now();
    const std::clock_t cpu_start = std::clock();
    OCTO_ASSIGN_OR_RETURN(out.image, renderer.RenderFullFrame(camera, params, options, &s));
    out.cpu_s_last_frame = static_cast<double>(std::clock() - cpu_start) / CLOCKS_PER_SEC;
    out.ms_last_frame = MsSince(wall_start);
    out.stats.ms_kernel += s.ms_kernel;
    out.stats.ms_upload += s.ms_upload;
    out.stats.passes += s.passes > 0 ? s.passes : 1;
    out.stats.samples += s.samples;
    out.stats.samples_skipped += s.samples_skipped;
    out.stats.requests += s.requests;
    out.stats.bricks_uploaded += s.bricks_uploaded;
    out.stats.finished_fraction = s.finished_fraction;
    out.stats.final = s.requests == 0;
    if (out.stats.final) break;
  }
  return out;
}

Status EncodeAndWrite(const render::RenderImage& image, encode::ImageFormat format, int quality,
                      const std::string& path) {
  // PNG keeps the alpha channel (straight, as the format requires); JPEG shows the image over
  // black.
  const encode::Rgba8Image pixels =
      encode::ToRgba8(image.rgba.data(), image.width, image.height,
                      format == encode::ImageFormat::kPng ? encode::AlphaMode::kStraight
                                                          : encode::AlphaMode::kOverBlack);
  OCTO_ASSIGN_OR_RETURN(std::vector<uint8_t> bytes, format == encode::ImageFormat::kPng
                                                        ? encode::EncodePng(pixels)
                                                        : encode::EncodeJpeg(pixels, quality));
  return WriteBytes(path, bytes);
}

// What RenderSlice needs from the command line and from RunRender's set-up.
struct SliceJob {
  AxisPosition slice;
  std::optional<double> um_per_pixel;  // --slice-zoom; unset: the cross-section fitted.
  int width = 0;
  int height = 0;
  double lod_bias = 0;
  double budget_ms = 0;
  int max_frames = kMaxFullFrames;
  bool refine = false;
  bool stats_json = false;
  encode::ImageFormat format = encode::ImageFormat::kPng;
  int quality = 90;
  std::string out_path;
  std::string input;
  std::string device;         // DeviceInfo::ToString().
  std::string octree_source;  // LoadedOctree::source.
  std::chrono::steady_clock::time_point start;
  uint64_t bricks_preloaded = 0;  // By UploadCoarseLevels, before the first frame.
};

// Renders, writes and reports the slice of `job` (the --slice path of RunRender); returns the exit
// status. REQUIRES: the pointers valid for the call; params match the octree's channels.
int RenderSlice(const SliceJob& job, const render::ComputeContext* context,
                render::ProgramCache* programs, render::DeviceOctree* device_octree,
                const render::Vec3& spacing, const render::RenderParams& params) {
  auto renderer = render::SliceRenderer::Create(context, programs, device_octree, spacing);
  if (!renderer.ok()) return Fail(job.input, renderer.status());
  const double ms_load = MsSince(job.start);

  // The plane at the given position or through the box's centre; the default fit unless zoomed.
  render::SliceView view;
  view.axis = job.slice.axis;
  view.position_um = PositionOrCentre(job.slice, (*renderer)->bounds());
  view.width = job.width;
  view.height = job.height;
  view.um_per_pixel = job.um_per_pixel;
  // Frames repeat until every wanted brick is resident (the image is then exactly the level).
  render::SliceOptions options;
  options.lod_bias = job.lod_bias;
  options.upload.max_ms = job.budget_ms;
  options.converge = true;
  options.max_frames = job.max_frames;
  render::SliceStats stats;
  const auto render_start = std::chrono::steady_clock::now();
  auto image = (*renderer)->Render(view, params, options, &stats);
  if (!image.ok()) return Fail(job.input, image.status());
  const double ms_total = MsSince(render_start);

  if (Status s = EncodeAndWrite(*image, job.format, job.quality, job.out_path); !s.ok()) {
    return Fail(job.out_path, s);
  }
  if (job.stats_json) {
    protocol::RenderReport report;
    report.ms_total = ms_total;
    report.ms_load = ms_load;  // ms_kernel and ms_upload are not measured apart for slices: 0.
    report.passes = stats.frames;
    report.bricks_uploaded = stats.bricks_uploaded;
    report.bricks_preloaded = job.bricks_preloaded;
    report.samples = stats.samples;
    report.requests = stats.requests;
    report.finished_fraction = stats.converged ? 1 : 0;
    report.final = stats.converged;
    report.refine = job.refine;
    report.width = job.width;
    report.height = job.height;
    report.mode = "slice";
    report.projection = "ortho";
    report.device = job.device;
    report.octree = job.octree_source;
    report.out = job.out_path;
    report.slice_axis = kAxisNames[job.slice.axis];
    report.slice_position_um = view.position_um;
    report.um_per_pixel = render::ResolveSliceFrame(view, (*renderer)->bounds()).um_per_pixel;
    report.level = stats.level;
    std::printf("%s\n", protocol::RenderReportJson(report).c_str());
  }
  return kExitOk;
}

}  // namespace

int RunRender(std::span<const std::string> args) {
  const auto start = std::chrono::steady_clock::now();
  Flags flags(
      "octoscope render INPUT|CACHE_DIR --out FILE.png|FILE.jpg [options]",
      "Renders one image of INPUT (any format of 'octoscope info'; its octree is built in RAM,\n"
      "or in --cache DIR and reused from there) or of an octree cache directory, with the\n"
      "OpenCL ray caster, or one axis-aligned slice of it (--slice). Camera and parameter\n"
      "files: docs/render_json.md; fields of --stats-json and slice orientation: docs/cli.md.");
  flags.SetPositionals("INPUT|CACHE_DIR", 1, 1);
  flags.AddValue("out", "FILE", "output image, .png (RGBA) or .jpg/.jpeg (RGB over black)");
  flags.AddValue("size", "WxH", "image size in pixels", "512x512");
  flags.AddValue("mode", "dvr|mip|minip", "compositing (overrides the parameter file)", "dvr");
  flags.AddValue("projection", "ortho|perspective",
                 "projection of a standard view (a camera file may set its own)", "ortho");
  flags.AddValue("view", "x|y|z|iso|CAMERA.json", "standard view fitted to the volume, or a file",
                 "z");
  flags.AddSwitch("refine", "refinement ray casting until the image is final (else full frames)");
  flags.AddValue("slice", "AXIS[@UM]",
                 "render the slice normal to AXIS (x|y|z) at UM µm (default: the centre)\n"
                 "                            instead of a 3-D view; --view does not apply");
  flags.AddValue("slice-zoom", "UM_PER_PIXEL", "pixel size of --slice",
                 "the volume's cross-section fitted");
  flags.AddValue("slice-planes", "AXIS[@UM],...",
                 "draw these slice planes into the 3-D view (x red, y green, z blue;\n"
                 "                            UM default: the centre)");
  flags.AddValue("params", "PARAMS.json", "render parameters", "as --defaults says");
  flags.AddValue(
      "defaults", "display|raw",
      "without --params: 'display' = as the browser opens the scan (the file's colours\n"
      "                            and windows, else distinct colours and auto-contrast from the\n"
      "                            histogram of all voxels); 'raw' = grey full-range channels",
      "display");
  flags.AddSwitch("stats-json", "print one JSON line of statistics on stdout");
  flags.AddSwitch(
      "cpu-reference",
      "render with the double-precision CPU reference renderer instead (the\n"
      "                            tests' oracle; one thread, slow; INPUT must be a scan)");
  flags.AddValue("device", "PREF", "OpenCL device: auto, gpu, cpu, N, P:D or a name", "auto");
  flags.AddValue("brick-buffer-mb", "N", "device brick buffer in MiB", "512");
  flags.AddValue("lod-bias", "F", "level-of-detail bias (+1: half resolution)", "0");
  flags.AddValue("scale", "F",
                 "render F x the size per axis (1/16..1) and upsample bilinearly to --size,\n"
                 "                            as the browser shows an interactive frame",
                 "1");
  flags.AddValue("step", "F", "sampling step in voxels (overrides the parameter file)", "1");
  flags.AddValue("budget-ms", "N", "upload budget per frame / pass in ms", "150");
  flags.AddValue("max-passes", "N",
                 "stop after N refinement passes or full frames (0: until final)", "0");
  flags.AddValue("quality", "N", "JPEG quality 1..100", "90");
  flags.AddValue("cache", "DIR", "build the octree into (or reuse it from) this cache directory");
  flags.AddValue("ram-mb", "N", "RAM budget in MiB for building and paging the octree",
                 "a quarter of RAM, <= 4096");
  AddVolumeFlags(flags);
  if (Status s = flags.Parse(args); !s.ok()) return Usage(s.message(), flags);
  if (auto d = flags.Get("defaults"); d && *d != "display" && *d != "raw") {
    return Usage("--defaults must be display or raw", flags);
  }
  if (flags.help_requested()) {
    std::printf("%s", flags.Help().c_str());
    return kExitOk;
  }

  // 1. Flags (usage errors, exit 64) before touching any file.
  const auto out_path = flags.Get("out");
  if (!out_path || out_path->empty()) return Usage("--out FILE is required", flags);
  auto format = encode::ImageFormatFromPath(*out_path);
  if (!format.ok()) return Usage(format.status().message(), flags);
  auto size = ParseSize(flags.Get("size").value_or("512x512"));
  if (!size.ok()) return Usage(size.status().message(), flags);
  const auto [width, height] = *size;
  std::optional<render::RenderMode> mode_flag;
  if (auto m = flags.Get("mode")) {
    mode_flag = render::RenderModeFromName(*m);
    if (!mode_flag) return Usage("--mode must be dvr, mip or minip", flags);
  }
  const auto projection = render::ProjectionFromName(flags.Get("projection").value_or("ortho"));
  if (!projection) return Usage("--projection must be ortho or perspective", flags);
  const std::string view = flags.Get("view").value_or("z");
  const auto standard_view = render::StandardViewFromName(view);
  auto brick_buffer_mb = flags.GetInt("brick-buffer-mb", 512, 1, int64_t{1} << 20);
  if (!brick_buffer_mb.ok()) return Usage(brick_buffer_mb.status().message(), flags);
  auto lod_bias = flags.GetDouble("lod-bias", 0);
  if (!lod_bias.ok()) return Usage(lod_bias.status().message(), flags);
  if (!(*lod_bias >= -8 && *lod_bias <= 16)) return Usage("--lod-bias must be in [-8, 16]", flags);
  auto scale = flags.GetDouble("scale", 1);
  if (!scale.ok()) return Usage(scale.status().message(), flags);
  if (!(*scale >= 1.0 / 16 && *scale <= 1)) return Usage("--scale must be in [1/16, 1]", flags);
  // The size the rays are cast at (the image is upsampled to width x height).
  const int render_width = std::max(1, static_cast<int>(std::lround(width * *scale)));
  const int render_height = std::max(1, static_cast<int>(std::lround(height * *scale)));
  std::optional<double> step;
  if (flags.Has("step")) {
    auto s = flags.GetDouble("step", 1);
    if (!s.ok()) return Usage(s.status().message(), flags);
    if (!(*s >= render::kMinStepVoxels && *s <= render::kMaxStepVoxels)) {
      return Usage("--step must be in [1/64, 64] voxels", flags);
    }
    step = *s;
  }
  auto budget_ms = flags.GetInt("budget-ms", 150, 1, 3'600'000);
  if (!budget_ms.ok()) return Usage(budget_ms.status().message(), flags);
  auto max_passes = flags.GetInt("max-passes", 0, 0, 1'000'000);
  if (!max_passes.ok()) return Usage(max_passes.status().message(), flags);
  auto quality = flags.GetInt("quality", 90, 1, 100);
  if (!quality.ok()) return Usage(quality.status().message(), flags);
  auto ram_mb = flags.GetInt("ram-mb", DefaultRamMb(), 16, int64_t{1} << 22);
  if (!ram_mb.ok()) return Usage(ram_mb.status().message(), flags);
  auto open_options = VolumeOptionsFromFlags(flags);
  if (!open_options.ok()) return Usage(open_options.status().message(), flags);
  const bool refine = flags.Has("refine");
  std::optional<AxisPosition> slice;
  if (auto text = flags.Get("slice")) {
    auto parsed = ParseAxisPosition(*text, "--slice");
    if (!parsed.ok()) return Usage(parsed.status().message(), flags);
    slice = *parsed;
    if (flags.Has("view")) {
      return Usage("--slice renders a slice instead of a 3-D view: drop --view", flags);
    }
    if (flags.Has("slice-planes")) {
      return Usage("--slice-planes draws into 3-D views: it cannot be used with --slice", flags);
    }
    if (flags.Has("scale")) return Usage("--scale applies to 3-D views, not to --slice", flags);
  }
  if (flags.Has("scale") && flags.Has("cpu-reference")) {
    return Usage("--cpu-reference renders at the full size: drop --scale", flags);
  }
  std::optional<double> slice_zoom;
  if (flags.Has("slice-zoom")) {
    if (!slice) return Usage("--slice-zoom needs --slice", flags);
    auto zoom = flags.GetDouble("slice-zoom", 1);
    if (!zoom.ok()) return Usage(zoom.status().message(), flags);
    if (!(*zoom > 0 && std::isfinite(*zoom))) {
      return Usage("--slice-zoom must be a positive number of µm per pixel", flags);
    }
    slice_zoom = *zoom;
  }
  std::vector<AxisPosition> plane_items;
  if (auto text = flags.Get("slice-planes")) {
    auto parsed = ParseSlicePlanes(*text);
    if (!parsed.ok()) return Usage(parsed.status().message(), flags);
    plane_items = std::move(*parsed);
  }
  const std::string& input = flags.positionals()[0];

  // 2. The JSON files are read (not yet parsed: the defaults depend on the volume) up front, so a
  //    missing file fails before a long build.
  std::optional<std::string> params_text, camera_text;
  if (auto path = flags.Get("params")) {
    auto text = ReadSmallFile(*path, protocol::kMaxRenderJsonBytes);
    if (!text.ok()) return Fail(*path, text.status());
    params_text = std::move(*text);
  }
  if (!slice && !standard_view) {
    auto text = ReadSmallFile(view, protocol::kMaxRenderJsonBytes);
    if (!text.ok()) return Fail(view, text.status());
    camera_text = std::move(*text);
  }

  // 3. The octree (opened, reused or built).
  OctreeLoadOptions load;
  load.open = *open_options;
  load.cache_dir = flags.Get("cache").value_or("");
  load.ram_bytes = static_cast<uint64_t>(*ram_mb) << 20;
  auto loaded = LoadOctree(input, load);
  if (!loaded.ok()) return Fail(input, loaded.status());
  LoadedOctree& tree = **loaded;
  const volume::VolumeInfo& info = tree.info;

  // 4. Parameters and camera for this volume.
  const volume::DataType stored_type =
      tree.value_maps.empty() ? volume::StoredTypeFor(info.dtype) : tree.value_maps[0].stored_type;
  // Without --params the scan looks as it does when the browser opens it: the file's colours
  // (else distinct defaults) and windows (else auto-contrast from the histogram of all voxels).
  const bool display_defaults = !params_text && flags.Get("defaults").value_or("display") != "raw";
  render::RenderParams params =
      display_defaults ? dataset::DefaultDisplayParams(info, stored_type,
                                                       tree.histogram ? &*tree.histogram : nullptr,
                                                       mode_flag.value_or(render::RenderMode::kDvr))
                       : render::DefaultRenderParams(info.channel_count(), stored_type,
                                                     mode_flag.value_or(render::RenderMode::kDvr));
  if (params_text) {
    auto parsed = protocol::ParseRenderParamsJson(*params_text, params);
    if (!parsed.ok()) return Fail(*flags.Get("params"), parsed.status());
    params = std::move(*parsed);
    if (flags.Has("mode")) params.mode = *mode_flag;  // The command line wins.
  }
  if (step) params.step_voxels = *step;
  const render::Vec3 spacing = render::PhysicalSpacing(info);
  const render::Box3 bounds = render::PhysicalBounds(info.size, spacing);
  // A 3-D view's cameras (a slice has none): at the output size, and at the size rendered.
  std::optional<render::Camera> camera, render_camera;
  if (!slice) {
    const auto make = [&](int w, int h) {
      return standard_view ? render::Camera::Standard(*standard_view, *projection, bounds, w, h)
                           : protocol::ParseCameraJson(*camera_text, *projection, w, h);
    };
    Result<render::Camera> made = make(width, height);
    if (!made.ok()) return Fail(standard_view ? input : view, made.status());
    camera = std::move(*made);
    made = make(render_width, render_height);
    if (!made.ok()) return Fail(standard_view ? input : view, made.status());
    render_camera = std::move(*made);
  }
  std::vector<render::SlicePlane> planes;
  for (const AxisPosition& item : plane_items) {
    planes.push_back({item.axis, PositionOrCentre(item, bounds), kPlaneColours[item.axis]});
  }

  // 4b. The CPU reference (benchmarks' oracle): the scan in RAM as stored values, one image.
  if (flags.Has("cpu-reference")) {
    if (slice || !planes.empty()) return Usage("--cpu-reference renders 3-D views only", flags);
    if (dataset::IsCacheDirectory(input)) {
      return Fail(input, InvalidArgumentError("--cpu-reference needs the scan, not a cache"));
    }
    auto source = io::OpenVolume(input, *open_options);
    if (!source.ok()) return Fail(input, source.status());
    auto volume = render::ReferenceVolume::Load(**source, tree.value_maps,
                                                static_cast<uint64_t>(*ram_mb) << 20);
    if (!volume.ok()) return Fail(input, volume.status());
    if (!(volume->spacing() == spacing)) {
      // --spacing overrides the file's (the octree's info has them applied; the reader not).
      std::vector<std::vector<uint16_t>> channels;
      for (int c = 0; c < volume->channel_count(); ++c) {
        const std::span<const uint16_t> data = volume->channel_data(c);
        channels.emplace_back(data.begin(), data.end());
      }
      volume = render::ReferenceVolume::FromStored(volume->size(), spacing, volume->stored_type(),
                                                   std::move(channels));
      if (!volume.ok()) return Fail(input, volume.status());
    }
    auto image = render::RenderReference(*volume, *camera, params);
    if (!image.ok()) return Fail(input, image.status());
    if (Status s = EncodeAndWrite(*image, *format, static_cast<int>(*quality), *out_path);
        !s.ok()) {
      return Fail(*out_path, s);
    }
    return kExitOk;
  }

  // 5. The device, the octree mirrored on it, the renderer.
  auto device = render::ChooseDevice(flags.Get("device").value_or("auto"));
  if (!device.ok()) {
    std::fprintf(stderr, "%s: no OpenCL device to render on: %s\n", kCommand,
                 device.status().message().c_str());
    return kExitBadInput;
  }
  auto context = render::ComputeContext::Create(*device);
  if (!context.ok()) return Fail(device->name, context.status());
  render::ProgramCache programs(&*context);
  render::DeviceOctreeOptions device_options;
  device_options.brick_buffer_bytes = static_cast<uint64_t>(*brick_buffer_mb) << 20;
  auto device_octree = render::DeviceOctree::Create(&*context, &tree.octree(), device_options);
  if (!device_octree.ok()) return Fail(device->name, device_octree.status());
  // The coarsest levels at once, so that the first frame shows data, not node averages.
  render::UploadStats preload;
  if (Status s = (*device_octree)->UploadCoarseLevels(render::kCoarseLevelBytes, &preload);
      !s.ok()) {
    return Fail(input, s);
  }
  // 6a. A slice view: its own renderer, frames until converged, written and reported there.
  if (slice) {
    SliceJob job;
    job.slice = *slice;
    job.um_per_pixel = slice_zoom;
    job.width = width;
    job.height = height;
    job.lod_bias = *lod_bias;
    job.budget_ms = static_cast<double>(*budget_ms);
    job.max_frames = *max_passes > 0 ? static_cast<int>(*max_passes) : kMaxFullFrames;
    job.refine = refine;
    job.stats_json = flags.Has("stats-json");
    job.format = *format;
    job.quality = static_cast<int>(*quality);
    job.out_path = *out_path;
    job.input = input;
    job.device = device->ToString();
    job.octree_source = tree.source;
    job.start = start;
    job.bricks_preloaded = preload.uploaded;
    return RenderSlice(job, &*context, &programs, device_octree->get(), spacing, params);
  }
  auto renderer =
      render::VolumeRenderer::Create(&*context, &programs, device_octree->get(), spacing);
  if (!renderer.ok()) return Fail(device->name, renderer.status());
  const double ms_load = MsSince(start);

  // 6. Render: full frames until nothing more is requested, or one refinement to the end.
  render::FrameOptions options;
  options.mode = refine ? render::FrameMode::kRefine : render::FrameMode::kFullFrame;
  options.lod_bias = *lod_bias;
  options.upload.max_ms = static_cast<double>(*budget_ms);
  options.max_passes = static_cast<int>(*max_passes);
  const auto render_start = std::chrono::steady_clock::now();
  Result<RenderOutcome> outcome = RenderOutcome{};
  if (refine) {
    render::FrameStats stats;
    auto image = (*renderer)->Render(*render_camera, params, options, &stats);
    if (image.ok()) {
      outcome = RenderOutcome{std::move(*image), std::move(stats)};
    } else {
      outcome = image.status();
    }
  } else {
    outcome = RenderFullFrames(**renderer, *render_camera, params, options,
                               *max_passes > 0 ? static_cast<int>(*max_passes) : kMaxFullFrames);
  }
  if (!outcome.ok()) return Fail(input, outcome.status());
  const double ms_total = MsSince(render_start);

  // 7. Upsampled to the output size (--scale), then the slice planes over it (an overlay: the
  //    volume does not hide them).
  render::RenderImage& image = outcome->image;
  double ms_upsample = 0;
  if (image.width != width || image.height != height) {
    const auto upsample_start = std::chrono::steady_clock::now();
    image = render::BilinearUpsample(image, width, height);  // No copy of a full-size image.
    ms_upsample = MsSince(upsample_start);
  }
  if (Status s = render::DrawSlicePlanes(&image, *camera, bounds, planes); !s.ok()) {
    return Fail(input, s);
  }

  // 8. Encode and write.
  if (Status s = EncodeAndWrite(image, *format, static_cast<int>(*quality), *out_path); !s.ok()) {
    return Fail(*out_path, s);
  }

  if (flags.Has("stats-json")) {
    const render::FrameStats& s = outcome->stats;
    protocol::RenderReport report;
    report.ms_total = ms_total;
    report.ms_kernel = s.ms_kernel;
    report.ms_upload = s.ms_upload;
    report.ms_load = ms_load;
    report.passes = s.passes;
    report.bricks_uploaded = s.bricks_uploaded;
    report.bricks_preloaded = preload.uploaded;
    report.scale = *scale;
    report.ms_upsample = ms_upsample;
    report.samples = s.samples;
    report.samples_skipped = s.samples_skipped;
    report.requests = s.requests;
    report.finished_fraction = s.finished_fraction;
    report.final = s.final;
    report.refine = refine;
    report.ms_last_frame = outcome->ms_last_frame;
    report.cpu_s_last_frame = outcome->cpu_s_last_frame;
    report.width = width;
    report.height = height;
    report.mode = std::string(render::RenderModeName(params.mode));
    report.projection = std::string(render::ProjectionName(camera->projection()));
    report.device = device->ToString();
    report.octree = tree.source;
    report.out = *out_path;
    report.slice_planes = static_cast<int>(planes.size());
    std::printf("%s\n", protocol::RenderReportJson(report).c_str());
  }
  return kExitOk;
}

}  // namespace octoscope::app
