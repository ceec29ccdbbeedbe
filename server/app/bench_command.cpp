// `octoscope bench render`: speed against error of the OpenCL renderer (docs/benchmarks.md,
// "Rendering"). Renders fixed views of a volume over a sweep of settings, compares every image
// with the double-precision CPU reference renderer, and measures the octree renderer against two
// baselines in the same run, on the same view: the plain dense OpenCL kernel (the volume as one
// device array, bench/baseline/dense_kernel.h) and the hand-written multi-threaded C++ loop
// (bench/baseline/cpu_raycaster.h).
//
// Flow: load the volume into RAM as stored uint16 (the C++ loop's input), build its octree in
// memory (the renderer's input), render the reference images ONCE per (view, mode, size) — at
// most --reference-size pixels square: larger images are compared on their central crop at full
// resolution — then, per setting, a fresh DeviceOctree (cold: nothing resident):
//   cold    the first full frame (averages and whatever the wanted levels' ancestors give),
//   steady  the first full frame that requests nothing more (the frame seen while interacting),
//   interactive  (lod_bias 0 settings) the same renderer after 10 more full frames with a 100 ms
//           kernel-time target (FrameOptions::target_frame_ms) and the server's interactive level
//           of detail (FrameOptions::lod_view_spacing off): the bias it settled at, its speed and
//           error,
//   refined a fresh device octree refined to completion (total time of all passes).
// Sweep: every view and mode at the first size with lod_bias 0, step 1, the large brick buffer;
// then, for the iso view, one setting changed at a time: lod_bias 1 and 2, step 0.5 and 2, the
// small brick buffer, and each further size. --headline-only keeps just the iso settings the
// headline ratios need (for large volumes, where the whole sweep takes too long).
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include "app/commands.h"
#include "app/flags.h"
#include "app/volume_options.h"
#include "baseline/cpu_raycaster.h"
#include "baseline/dense_kernel.h"
#include "io/open_volume.h"
#include "io/synthetic_embryo.h"
#include "octree/octree.h"
#include "paging/memory_page_store.h"
#include "paging/page_cache.h"
#include "protocol/render_bench_report.h"
#include "render/camera.h"
#include "render/device.h"
#include "render/device_octree.h"
#include "render/program_cache.h"
#include "render/reference_renderer.h"
#include "render/render_params.h"
#include "render/volume_renderer.h"
#include "util/strings.h"
#include "volume/value_map.h"

namespace octoscope::app {
namespace {

using protocol::RenderBenchHeadline;
using protocol::RenderBenchReport;
using protocol::RenderBenchRow;
using render::Camera;
using render::RenderImage;
using render::RenderMode;
using render::RenderParams;

constexpr const char* kCommand = "octoscope bench render";
constexpr double kPsnrCap = 99;  // PSNR of (nearly) identical images, so every number is finite.

double MsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
      .count();
}

int Usage(const std::string& message, const Flags& flags) {
  std::fprintf(stderr, "%s: %s\n\n%s", kCommand, message.c_str(), flags.Help().c_str());
  return kExitUsage;
}

int Fail(const std::string& message) {
  std::string line = message;
  std::replace(line.begin(), line.end(), '\n', ' ');
  std::fprintf(stderr, "%s: %s\n", kCommand, line.c_str());
  return kExitBadInput;
}

Result<std::vector<int>> ParseSizes(const std::string& text) {
  std::vector<int> sizes;
  for (std::string_view part : Split(text, ',')) {
    std::optional<int64_t> v = ParseInt64(part);
    if (!v || *v < 8 || *v > 4096) {
      return InvalidArgumentError("--sizes: '" + Printable(part) +
                                  "' must be an integer in 8..4096");
    }
    sizes.push_back(static_cast<int>(*v));
  }
  if (sizes.empty()) return InvalidArgumentError("--sizes: empty");
  return sizes;
}

// ---------------------------------------------------------------------------------------------
// The volume in RAM (stored values) and its octree.

struct LoadedVolume {
  volume::VolumeInfo info;
  std::string description;
  volume::DataType stored_type = volume::DataType::kUint16;
  // The voxels as stored values: the reference renderer's input, copied for the C++ loop.
  std::unique_ptr<render::ReferenceVolume> volume;
  RenderParams dvr;  // The bench's appearance per mode (BenchParams).
  RenderParams mip;

  int channel_count() const { return volume->channel_count(); }
  std::span<const uint16_t> channel(int c) const { return volume->channel_data(c); }
  // The bench's parameters for `mode` at `step`.
  RenderParams Params(RenderMode mode, double step) const {
    RenderParams p = mode == RenderMode::kDvr ? dvr : mip;
    p.step_voxels = step;
    return p;
  }
};

// Reads all of `source` as stored values (ReferenceVolume::Load, the fixed 8/16-bit value map).
Result<LoadedVolume> LoadVolume(io::VolumeSource& source, std::string description) {
  LoadedVolume v;
  v.info = source.info();
  v.description = std::move(description);
  const volume::DataType dtype = v.info.dtype;
  if (volume::BytesPerSample(dtype) > 2) {
    return InvalidArgumentError("bench render reads 8- and 16-bit data only (this is " +
                                std::string(volume::NumpyName(dtype)) + ")");
  }
  const volume::ValueMap map = volume::FixedValueMap(dtype);
  v.stored_type = map.stored_type;
  const std::vector<volume::ValueMap> maps(v.info.channel_count(), map);
  OCTO_ASSIGN_OR_RETURN(render::ReferenceVolume volume,
                        render::ReferenceVolume::Load(source, maps, ~uint64_t{0}));
  v.volume = std::make_unique<render::ReferenceVolume>(std::move(volume));
  return v;
}

struct InMemoryOctree {
  std::unique_ptr<paging::MemoryPageStore> store;
  std::unique_ptr<paging::PageCache> cache;
  std::unique_ptr<octree::Octree> tree;
};

// Builds the octree of `v` in memory, brick layer by brick layer, with the build command's
// homogeneity rule (threshold of each channel's data range).
Result<InMemoryOctree> BuildInMemory(const LoadedVolume& v, int64_t brick, double threshold) {
  octree::OctreeOptions options;
  options.brick_size = {brick, brick, brick};
  options.bytes_per_sample = static_cast<int>(volume::BytesPerSample(v.stored_type));
  options.homogeneity_threshold = threshold;
  for (int c = 0; c < v.channel_count(); ++c) {
    const std::span<const uint16_t> ch = v.channel(c);
    const auto [lo, hi] = std::minmax_element(ch.begin(), ch.end());
    options.value_range.push_back(static_cast<uint32_t>(*hi - *lo));
  }
  InMemoryOctree t;
  const uint64_t bytes = v.info.VoxelBytes();
  // Pages of 8 stored bricks (a page must hold at least one), as the test scenes use.
  const uint64_t stored_brick = static_cast<uint64_t>((brick + 2) * (brick + 2) * (brick + 2)) *
                                v.channel_count() * options.bytes_per_sample;
  t.store =
      std::make_unique<paging::MemoryPageStore>(std::max(stored_brick * 8, uint64_t{1} << 20));
  t.cache = std::make_unique<paging::PageCache>(t.store.get(), bytes + (uint64_t{256} << 20));
  volume::VolumeInfo info = v.info;
  OCTO_ASSIGN_OR_RETURN(t.tree, octree::Octree::Create(info, options, t.cache.get()));
  const auto& n = v.info.size;
  const size_t plane = static_cast<size_t>(n[0] * n[1]);
  const int sample_bytes = options.bytes_per_sample;
  std::vector<std::byte> narrow;
  for (int c = 0; c < v.channel_count(); ++c) {
    for (int64_t z0 = 0; z0 < n[2]; z0 += brick) {
      const int64_t z1 = std::min(n[2], z0 + brick);
      const uint16_t* first = v.channel(c).data() + plane * z0;
      const size_t count = plane * static_cast<size_t>(z1 - z0);
      std::span<const std::byte> data;
      if (sample_bytes == 1) {
        narrow.resize(count);
        for (size_t i = 0; i < count; ++i) narrow[i] = static_cast<std::byte>(first[i]);
        data = narrow;
      } else {
        data = std::as_bytes(std::span<const uint16_t>(first, count));
      }
      OCTO_RETURN_IF_ERROR(t.tree->Insert(c, octree::Box{{0, 0, z0}, {n[0], n[1], z1}}, data));
    }
  }
  return t;
}

// Bench appearance: per channel a window from the data's histogram (the `window_low`
// percentile — 60 by default, mostly background — to the 99.9th), the file's colour or a palette
// colour, DVR opacity 0.3.
RenderParams BenchParams(const LoadedVolume& v, RenderMode mode, double window_low) {
  static constexpr std::array<std::array<double, 3>, 4> kPalette = {
      {{0.2, 1, 0.3}, {1, 0.2, 0.8}, {0.2, 0.8, 1}, {1, 0.9, 0.2}}};
  RenderParams params = render::DefaultRenderParams(v.channel_count(), v.stored_type, mode);
  for (int c = 0; c < v.channel_count(); ++c) {
    std::vector<uint64_t> histogram(65536, 0);
    const std::span<const uint16_t> ch = v.channel(c);
    for (size_t i = 0; i < ch.size(); i += 7) ++histogram[ch[i]];  // A 1/7 sample is plenty.
    const uint64_t total = (ch.size() + 6) / 7;
    auto percentile = [&](double p) {
      uint64_t seen = 0;
      for (int value = 0; value < 65536; ++value) {
        seen += histogram[value];
        if (seen >= p * total) return value;
      }
      return 65535;
    };
    const double lo = percentile(window_low / 100);
    const double hi = std::max(lo + 2, static_cast<double>(percentile(0.999)));
    render::ChannelParams& cp = params.channels[c];
    cp.window = hi - lo;
    cp.level = (hi + lo) / 2;
    cp.opacity_scale = 0.3;
    if (static_cast<size_t>(c) < v.info.channels.size() && v.info.channels[c].color) {
      const volume::Rgba& rgba = *v.info.channels[c].color;
      cp.color = {rgba.r / 255.0, rgba.g / 255.0, rgba.b / 255.0};
    } else {
      cp.color = kPalette[c % kPalette.size()];
    }
  }
  return params;
}

// ---------------------------------------------------------------------------------------------
// Views, settings, references and image errors.

constexpr std::array<const char*, 4> kViewNames = {"z", "x", "iso", "persp"};

Result<Camera> ViewCamera(const std::string& view, const render::Box3& box, int size) {
  if (view == "z") {
    return Camera::Standard(render::StandardView::kZ, render::Projection::kOrthographic, box, size,
                            size);
  }
  if (view == "x") {
    return Camera::Standard(render::StandardView::kX, render::Projection::kOrthographic, box, size,
                            size);
  }
  if (view == "iso") {
    return Camera::Standard(render::StandardView::kIso, render::Projection::kOrthographic, box,
                            size, size);
  }
  return Camera::Standard(render::StandardView::kY, render::Projection::kPerspective, box, size,
                          size);
}

// The central crop x crop pixels of `camera` as a camera of their own (same pixel centres).
Result<Camera> CropCamera(const Camera& camera, int crop) {
  const double scale = static_cast<double>(crop) / camera.height();
  const double pi = std::acos(-1.0);
  const double fov = 2 * std::atan(std::tan(camera.fov_y_degrees() * pi / 360) * scale) * 180 / pi;
  return Camera::LookAt(camera.projection(), camera.position(),
                        camera.position() + camera.forward(), camera.up(), crop, crop, fov,
                        camera.ortho_height() * scale);
}

struct ImageError {
  double psnr = kPsnrCap;
  double max_abs = 0;
};

// `image` (size S) against `reference` (its central crop, size R <= S).
ImageError CompareWithReference(const RenderImage& image, const RenderImage& reference) {
  ImageError e;
  const int offset = (image.width - reference.width) / 2;
  double sum_sq = 0;
  uint64_t n = 0;
  for (int y = 0; y < reference.height; ++y) {
    for (int x = 0; x < reference.width; ++x) {
      const auto a = image.Pixel(x + offset, y + offset);
      const auto b = reference.Pixel(x, y);
      for (int k = 0; k < 4; ++k) {
        double d = std::abs(static_cast<double>(a[k]) - b[k]);
        if (!std::isfinite(d)) d = 1;
        e.max_abs = std::max(e.max_abs, d);
        if (k < 3) {
          sum_sq += d * d;
          ++n;
        }
      }
    }
  }
  const double mse = n ? sum_sq / static_cast<double>(n) : 0;
  e.psnr = mse > 0 ? std::min(kPsnrCap, 10 * std::log10(1 / mse)) : kPsnrCap;
  return e;
}

struct Setting {
  std::string view;
  RenderMode mode;
  int size;
  double lod_bias;
  double step;
  bool small_buffer;
};

std::vector<Setting> BuildSweep(const std::vector<int>& sizes, bool headline_only) {
  std::vector<Setting> sweep;
  const int base = sizes[0];
  if (headline_only) {
    // Just what the headlines need: iso at the base size, and MIP at the largest size.
    const int big = *std::max_element(sizes.begin(), sizes.end());
    sweep.push_back({"iso", RenderMode::kDvr, base, 0, 1, false});
    sweep.push_back({"iso", RenderMode::kMip, base, 0, 1, false});
    if (big != base) sweep.push_back({"iso", RenderMode::kMip, big, 0, 1, false});
    return sweep;
  }
  for (const char* view : kViewNames) {
    for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip}) {
      sweep.push_back({view, mode, base, 0, 1, false});
    }
  }
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip}) {
    for (double lod : {1.0, 2.0}) sweep.push_back({"iso", mode, base, lod, 1, false});
    for (double step : {0.5, 2.0}) sweep.push_back({"iso", mode, base, 0, step, false});
    sweep.push_back({"iso", mode, base, 0, 1, true});
    for (size_t i = 1; i < sizes.size(); ++i) sweep.push_back({"iso", mode, sizes[i], 0, 1, false});
  }
  return sweep;
}

using ReferenceKey = std::tuple<std::string, RenderMode, int>;  // View, mode, image size.

// Renders every reference image on all cores (RenderReference is reentrant), each at
// min(size, reference_size) pixels: the central crop of larger images.
Result<std::map<ReferenceKey, RenderImage>> RenderReferences(const render::ReferenceVolume& volume,
                                                             const LoadedVolume& loaded,
                                                             const std::vector<ReferenceKey>& keys,
                                                             int reference_size,
                                                             double reference_step) {
  std::vector<RenderImage> images(keys.size());
  std::vector<Status> errors(keys.size());
  std::atomic<size_t> next{0};
  auto work = [&] {
    for (size_t i = next++; i < keys.size(); i = next++) {
      const auto& [view, mode, size] = keys[i];
      const RenderParams params = loaded.Params(mode, reference_step);
      Result<Camera> camera = ViewCamera(view, volume.bounds(), size);
      if (camera.ok() && size > reference_size) camera = CropCamera(*camera, reference_size);
      if (!camera.ok()) {
        errors[i] = camera.status();
        continue;
      }
      Result<RenderImage> image = render::RenderReference(volume, *camera, params);
      if (!image.ok()) {
        errors[i] = image.status();
        continue;
      }
      images[i] = std::move(*image);
    }
  };
  std::vector<std::thread> threads;
  const unsigned n = std::max(1u, std::thread::hardware_concurrency());
  for (unsigned k = 1; k < n; ++k) threads.emplace_back(work);
  work();
  for (std::thread& t : threads) t.join();
  std::map<ReferenceKey, RenderImage> out;
  for (size_t i = 0; i < keys.size(); ++i) {
    OCTO_RETURN_IF_ERROR(errors[i]);
    out[keys[i]] = std::move(images[i]);
  }
  return out;
}

// ---------------------------------------------------------------------------------------------
// Measuring the renderer.

struct Bench {
  const render::ComputeContext* context;
  render::ProgramCache* programs;
  octree::Octree* tree;
  const LoadedVolume* loaded;
  render::Vec3 spacing;
  render::Box3 box;
  uint64_t small_bytes;
  uint64_t large_bytes;
  const std::map<ReferenceKey, RenderImage>* references;
};

struct Renderer {
  std::unique_ptr<render::DeviceOctree> octree;
  std::unique_ptr<render::VolumeRenderer> renderer;
};

Result<Renderer> FreshRenderer(const Bench& b, uint64_t brick_bytes) {
  Renderer r;
  render::DeviceOctreeOptions options;
  options.brick_buffer_bytes = brick_bytes;
  OCTO_ASSIGN_OR_RETURN(r.octree, render::DeviceOctree::Create(b.context, b.tree, options));
  OCTO_ASSIGN_OR_RETURN(
      r.renderer, render::VolumeRenderer::Create(b.context, b.programs, r.octree.get(), b.spacing));
  return r;
}

RenderBenchRow RowFor(const Setting& s, const char* kind, double brick_mb) {
  RenderBenchRow row;
  row.view = s.view;
  row.mode = std::string(render::RenderModeName(s.mode));
  row.frame_kind = kind;
  row.size = s.size;
  row.lod_bias = s.lod_bias;
  row.step = s.step;
  row.brick_mb = brick_mb;
  return row;
}

void FillTiming(RenderBenchRow& row, double ms, const render::FrameStats& stats) {
  row.ms = ms;
  row.fps = ms > 0 ? 1000 / ms : 0;
  // Kernel throughput: channel samples per second of kernel time.
  row.msamples_per_s = stats.ms_kernel > 0 ? stats.samples / (stats.ms_kernel * 1e3) : 0;
}

void FillError(RenderBenchRow& row, const RenderImage& image, const RenderImage& reference) {
  const ImageError e = CompareWithReference(image, reference);
  row.psnr_db = e.psnr;
  row.max_err = e.max_abs;
}

constexpr int kMaxWarmupFrames = 10;  // Full frames settle in 2 when the bricks fit.
// "interactive" rows: full frames with FrameOptions::target_frame_ms, the last of this many.
constexpr double kInteractiveTargetMs = 100;
constexpr int kInteractiveFrames = 10;

// Runs a full frame and one refinement pass of each mode at `size` on a throwaway renderer: the
// OpenCL driver may compile kernels per launch size (PoCL does), which no cold frame should pay.
Status WarmUpSize(const Bench& b, int size) {
  OCTO_ASSIGN_OR_RETURN(Camera camera, ViewCamera("iso", b.box, size));
  OCTO_ASSIGN_OR_RETURN(Renderer r, FreshRenderer(b, b.small_bytes));
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip}) {
    const RenderParams params = b.loaded->Params(mode, 1);
    render::FrameOptions options;
    OCTO_RETURN_IF_ERROR(r.renderer->RenderFullFrame(camera, params, options).status());
    options.mode = render::FrameMode::kRefine;
    options.max_passes = 1;
    OCTO_RETURN_IF_ERROR(r.renderer->Render(camera, params, options).status());
  }
  return Status::Ok();
}
constexpr int kMaxPasses = 5000;

// The three rows (cold, steady, refined) of one setting.
Status MeasureSetting(const Bench& b, const Setting& s, std::vector<RenderBenchRow>* rows) {
  const uint64_t brick_bytes = s.small_buffer ? b.small_bytes : b.large_bytes;
  const double brick_mb = static_cast<double>(brick_bytes) / (1 << 20);
  const RenderParams params = b.loaded->Params(s.mode, s.step);
  OCTO_ASSIGN_OR_RETURN(Camera camera, ViewCamera(s.view, b.box, s.size));
  const RenderImage& reference = b.references->at({s.view, s.mode, s.size});

  // Full frames from cold until a frame requests nothing (or the warm-up limit).
  {
    OCTO_ASSIGN_OR_RETURN(Renderer r, FreshRenderer(b, brick_bytes));
    render::FrameOptions options;
    options.lod_bias = s.lod_bias;
    render::FrameStats stats;
    OCTO_ASSIGN_OR_RETURN(RenderImage image,
                          r.renderer->RenderFullFrame(camera, params, options, &stats));
    RenderBenchRow cold = RowFor(s, "cold", brick_mb);
    FillTiming(cold, stats.ms_total, stats);
    cold.bricks_uploaded = stats.bricks_uploaded;
    cold.passes = 1;
    FillError(cold, image, reference);
    rows->push_back(cold);
    int frames = 1;
    while (stats.requests > 0 && frames < kMaxWarmupFrames) {
      stats = {};
      OCTO_ASSIGN_OR_RETURN(image, r.renderer->RenderFullFrame(camera, params, options, &stats));
      ++frames;
    }
    RenderBenchRow steady = RowFor(s, stats.requests > 0 ? "unsteady" : "steady", brick_mb);
    FillTiming(steady, stats.ms_total, stats);
    steady.bricks_uploaded = r.octree->total_uploaded();
    steady.passes = frames;
    FillError(steady, image, reference);
    rows->push_back(steady);
    // Interaction: the same view with the frame-time target and the server's interactive level
    // of detail (footprints in the finest spacing); the bias settles where frames take about the
    // target (lod_bias column: the bias the last frame ran at).
    if (s.lod_bias == 0) {
      options.target_frame_ms = kInteractiveTargetMs;
      options.lod_view_spacing = false;
      options.view = 1;
      for (int i = 0; i < kInteractiveFrames; ++i) {
        stats = {};
        OCTO_ASSIGN_OR_RETURN(image, r.renderer->RenderFullFrame(camera, params, options, &stats));
      }
      RenderBenchRow interactive = RowFor(s, "interactive", brick_mb);
      interactive.lod_bias = stats.lod_bias_used;
      FillTiming(interactive, stats.ms_total, stats);
      interactive.bricks_uploaded = r.octree->total_uploaded();
      interactive.passes = kInteractiveFrames;
      FillError(interactive, image, reference);
      rows->push_back(interactive);
    }
  }
  // Refinement from cold to completion.
  {
    OCTO_ASSIGN_OR_RETURN(Renderer r, FreshRenderer(b, brick_bytes));
    render::FrameOptions options;
    options.mode = render::FrameMode::kRefine;
    options.lod_bias = s.lod_bias;
    options.max_passes = kMaxPasses;
    render::FrameStats stats;
    OCTO_ASSIGN_OR_RETURN(RenderImage image, r.renderer->Render(camera, params, options, &stats));
    RenderBenchRow refined = RowFor(s, stats.final ? "refined" : "refined*", brick_mb);
    FillTiming(refined, stats.ms_total, stats);
    refined.bricks_uploaded = stats.bricks_uploaded;
    refined.passes = stats.passes;
    FillError(refined, image, reference);
    rows->push_back(refined);
  }
  return Status::Ok();
}

template <typename T>
T Median(std::vector<T> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

// One renderer's level-0 frames of the headline view: medians of the timed repeats, the image's
// error against the reference.
struct Timed {
  double msamples = 0;   // Channel samples / kernel ms.
  double ms = 0;         // Whole frame call (median).
  double ms_kernel = 0;  // Kernel only (median).
  uint64_t samples = 0;
  uint64_t skipped = 0;  // Channel samples empty-space skipping jumped over.
  ImageError error;      // Against the CPU reference (its central crop).
  RenderImage image;
};

struct KernelVsLoop {
  Timed octree;        // The octree renderer, empty-space skipping on (the product).
  Timed octree_dense;  // The same, skipping off: the plain kernel's sample count.
  Timed dense;         // The plain dense kernel (bench/baseline/dense_kernel.h), its faster form:
  double dense_packet_msamples = 0;  // Eight rays per work item (where the device takes them).
  double dense_single_msamples = 0;  // One ray per work item.
  bool dense_packets = false;        // The device took the eight-ray form (else both are one ray).
  double loop_msamples = 0;
  double loop_ms = 0;
  uint64_t loop_samples = 0;
  int loop_threads = 0;
  ImageError loop_error;
  double kernel_vs_loop_max_err = 0;   // Level-0 octree image against the loop's.
  double octree_vs_dense_max_err = 0;  // Level-0 octree image (skipping off) against the dense one.
  bool steady = false;
};

ImageError ErrorAgainst(const RenderImage& image, const Bench& b, RenderMode mode, int size) {
  auto it = b.references->find({"iso", mode, size});
  return it != b.references->end() ? CompareWithReference(image, it->second) : ImageError{};
}

// One timed frame of a renderer.
struct FrameTiming {
  double ms = 0;
  double ms_kernel = 0;
  uint64_t samples = 0;
  uint64_t skipped = 0;
};

// Medians of the frames' timings.
Timed Summarize(const std::vector<FrameTiming>& frames, RenderImage image) {
  Timed t;
  std::vector<double> ms, kernel_ms, rate;
  for (const FrameTiming& f : frames) {
    ms.push_back(f.ms);
    kernel_ms.push_back(f.ms_kernel);
    rate.push_back(f.ms_kernel > 0 ? f.samples / (f.ms_kernel * 1e3) : 0);
    t.samples = f.samples;
    t.skipped = f.skipped;
  }
  t.ms = Median(ms);
  t.ms_kernel = Median(kernel_ms);
  t.msamples = Median(rate);
  t.image = std::move(image);
  return t;
}

// A renderer at level 0 with everything the view needs resident (made so by a refinement, then
// full frames until none requests anything); *steady tells whether that was reached.
Result<Renderer> ResidentLevel0(const Bench& b, const Camera& camera, const RenderParams& params,
                                const render::FrameOptions& options, bool* steady) {
  OCTO_ASSIGN_OR_RETURN(Renderer r, FreshRenderer(b, b.large_bytes));
  render::FrameOptions refine = options;
  refine.mode = render::FrameMode::kRefine;
  refine.max_passes = kMaxPasses;
  render::FrameStats stats;
  OCTO_RETURN_IF_ERROR(r.renderer->Render(camera, params, refine, &stats).status());
  *steady = false;
  for (int frame = 0; frame < kMaxWarmupFrames && !*steady; ++frame) {
    stats = {};
    OCTO_RETURN_IF_ERROR(r.renderer->RenderFullFrame(camera, params, options, &stats).status());
    *steady = stats.requests == 0;
  }
  return r;
}

// Headline (a): at level 0 with everything resident, the octree renderer (skipping on and off),
// the plain dense kernel and the C++ loop, same view, size and step. The three OpenCL renderers
// take turns frame by frame (load changes on a shared machine hit them alike); medians of
// `repeats` frames each.
Result<KernelVsLoop> MeasureKernelVsLoop(const Bench& b, bench::DenseKernel& dense,
                                         const bench::CpuRaycaster& loop, RenderMode mode, int size,
                                         int repeats) {
  KernelVsLoop k;
  const RenderParams params = b.loaded->Params(mode, 1);
  OCTO_ASSIGN_OR_RETURN(Camera camera, ViewCamera("iso", b.box, size));
  render::FrameOptions on;
  on.lod_bias = -32;  // Level 0 everywhere.
  render::FrameOptions off = on;
  off.skip_empty_space = false;
  bool steady_on = false, steady_off = false;
  OCTO_ASSIGN_OR_RETURN(Renderer r_on, ResidentLevel0(b, camera, params, on, &steady_on));
  OCTO_ASSIGN_OR_RETURN(Renderer r_off, ResidentLevel0(b, camera, params, off, &steady_off));
  k.steady = steady_on && steady_off;
  // The plain kernel in both forms, eight rays per work item and one (which is faster depends on
  // the view: rays two voxels apart share fewer cache lines in a packet); the baseline is the
  // faster. Their first launches build their programs (and PoCL compiles per launch size).
  for (bool packets : {true, false}) {
    dense.set_packets(packets);
    OCTO_RETURN_IF_ERROR(dense.Render(camera, params).status());
  }
  std::vector<FrameTiming> t_on, t_off, t_packet, t_single;
  RenderImage i_on, i_off, i_packet, i_single;
  for (int i = 0; i < repeats; ++i) {
    for (auto [r, options, timings, image] :
         {std::tuple{&r_on, &on, &t_on, &i_on}, std::tuple{&r_off, &off, &t_off, &i_off}}) {
      render::FrameStats s;
      OCTO_ASSIGN_OR_RETURN(*image, r->renderer->RenderFullFrame(camera, params, *options, &s));
      timings->push_back({s.ms_total, s.ms_kernel, s.samples, s.samples_skipped});
    }
    for (auto [packets, timings, image] :
         {std::tuple{true, &t_packet, &i_packet}, std::tuple{false, &t_single, &i_single}}) {
      dense.set_packets(packets);
      bench::DenseKernelStats s;
      OCTO_ASSIGN_OR_RETURN(*image, dense.Render(camera, params, &s));
      timings->push_back({s.ms_total, s.ms_kernel, s.samples});
      if (packets) k.dense_packets = s.packets;
    }
  }
  dense.set_packets(true);
  k.octree = Summarize(t_on, std::move(i_on));
  k.octree_dense = Summarize(t_off, std::move(i_off));
  Timed packet = Summarize(t_packet, std::move(i_packet));
  Timed single = Summarize(t_single, std::move(i_single));
  k.dense_packet_msamples = packet.msamples;
  k.dense_single_msamples = single.msamples;
  k.dense = std::move(packet.ms_kernel <= single.ms_kernel ? packet : single);

  std::vector<double> loop_ms;
  RenderImage loop_image;
  for (int i = 0; i < repeats; ++i) {
    bench::CpuRaycastStats loop_stats;
    OCTO_ASSIGN_OR_RETURN(loop_image, loop.Render(camera, params, 0, &loop_stats));
    loop_ms.push_back(loop_stats.ms);
    k.loop_samples = loop_stats.samples;
    k.loop_threads = loop_stats.threads;
  }
  k.loop_ms = Median(loop_ms);
  k.loop_msamples = k.loop_ms > 0 ? k.loop_samples / (k.loop_ms * 1e3) : 0;
  k.kernel_vs_loop_max_err = CompareWithReference(k.octree.image, loop_image).max_abs;
  k.octree_vs_dense_max_err = CompareWithReference(k.octree_dense.image, k.dense.image).max_abs;
  for (Timed* t : {&k.octree, &k.octree_dense, &k.dense}) {
    t->error = ErrorAgainst(t->image, b, mode, size);
  }
  k.loop_error = ErrorAgainst(loop_image, b, mode, size);
  return k;
}

// ---------------------------------------------------------------------------------------------
// Output: the markdown table and the speed-vs-error SVG.

std::string Format(const char* format, double v) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), format, v);
  return buf;
}

std::string MarkdownTable(const std::vector<RenderBenchRow>& rows) {
  std::ostringstream out;
  out << "| view | mode | frame kind | size | lod_bias | step | brick_mb | ms/frame | fps | "
         "Msamples/s | bricks_uploaded | passes | PSNR (dB) | max_err |\n";
  out << "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const RenderBenchRow& r : rows) {
    out << "| " << r.view << " | " << r.mode << " | " << r.frame_kind << " | " << r.size << "² | "
        << Format("%g", r.lod_bias) << " | " << Format("%g", r.step) << " | "
        << Format("%.3g", r.brick_mb) << " | " << Format("%.1f", r.ms) << " | "
        << Format("%.2f", r.fps) << " | " << Format("%.1f", r.msamples_per_s) << " | "
        << r.bricks_uploaded << " | " << r.passes << " | " << Format("%.1f", r.psnr_db) << " | "
        << Format("%.4f", r.max_err) << " |\n";
  }
  return out.str();
}

std::string SvgEscape(const std::string& text) {
  std::string out;
  for (char c : text) {
    if (c == '<') {
      out += "&lt;";
    } else if (c == '>') {
      out += "&gt;";
    } else if (c == '&') {
      out += "&amp;";
    } else {
      out += c;
    }
  }
  return out;
}

// x = ms per frame (log scale), y = PSNR; colour = mode, marker = frame kind.
std::string SpeedErrorSvg(const std::vector<RenderBenchRow>& rows, const std::string& title) {
  constexpr double kW = 960, kH = 600, kLeft = 70, kRight = 30, kTop = 40, kBottom = 60;
  double lo_ms = 1e300, hi_ms = 0, lo_db = 1e300, hi_db = -1e300;
  for (const RenderBenchRow& r : rows) {
    const double ms = std::max(r.ms, 1e-3);
    lo_ms = std::min(lo_ms, ms);
    hi_ms = std::max(hi_ms, ms);
    lo_db = std::min(lo_db, r.psnr_db);
    hi_db = std::max(hi_db, r.psnr_db);
  }
  if (rows.empty()) lo_ms = hi_ms = 1, lo_db = hi_db = 0;
  const double x0 = std::floor(std::log10(lo_ms)),
               x1 = std::max(x0 + 1, std::ceil(std::log10(hi_ms)));
  const double y0 = std::floor(lo_db / 5) * 5, y1 = std::max(y0 + 5, std::ceil(hi_db / 5) * 5);
  auto px = [&](double ms) {
    return kLeft + (std::log10(std::max(ms, 1e-3)) - x0) / (x1 - x0) * (kW - kLeft - kRight);
  };
  auto py = [&](double db) { return kH - kBottom - (db - y0) / (y1 - y0) * (kH - kTop - kBottom); };
  std::ostringstream s;
  s << "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n";
  s << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << kW << "\" height=\"" << kH
    << "\" viewBox=\"0 0 " << kW << " " << kH << "\" font-family=\"sans-serif\">\n";
  s << "<rect x=\"0\" y=\"0\" width=\"" << kW << "\" height=\"" << kH << "\" fill=\"white\"/>\n";
  s << "<text x=\"" << kW / 2 << "\" y=\"22\" text-anchor=\"middle\" font-size=\"15\">"
    << SvgEscape(title) << "</text>\n";
  // Grid: decades of ms, 5 dB steps.
  for (double e = x0; e <= x1 + 1e-9; e += 1) {
    const double x = px(std::pow(10.0, e));
    s << "<line x1=\"" << x << "\" y1=\"" << kTop << "\" x2=\"" << x << "\" y2=\"" << kH - kBottom
      << "\" stroke=\"#ddd\"/>\n";
    s << "<text x=\"" << x << "\" y=\"" << kH - kBottom + 18 << "\" text-anchor=\"middle\" "
      << "font-size=\"12\">" << Format("%g", std::pow(10.0, e)) << "</text>\n";
  }
  for (double db = y0; db <= y1 + 1e-9; db += 5) {
    const double y = py(db);
    s << "<line x1=\"" << kLeft << "\" y1=\"" << y << "\" x2=\"" << kW - kRight << "\" y2=\"" << y
      << "\" stroke=\"#ddd\"/>\n";
    s << "<text x=\"" << kLeft - 6 << "\" y=\"" << y + 4
      << "\" text-anchor=\"end\" font-size=\"12\">" << Format("%g", db) << "</text>\n";
  }
  s << "<rect x=\"" << kLeft << "\" y=\"" << kTop << "\" width=\"" << kW - kLeft - kRight
    << "\" height=\"" << kH - kTop - kBottom << "\" fill=\"none\" stroke=\"black\"/>\n";
  s << "<text x=\"" << (kLeft + kW - kRight) / 2 << "\" y=\"" << kH - 18
    << "\" text-anchor=\"middle\" font-size=\"13\">ms per frame (log scale)</text>\n";
  s << "<text x=\"18\" y=\"" << (kTop + kH - kBottom) / 2 << "\" text-anchor=\"middle\" "
    << "font-size=\"13\" transform=\"rotate(-90 18 " << (kTop + kH - kBottom) / 2
    << ")\">PSNR vs CPU reference (dB)</text>\n";
  for (const RenderBenchRow& r : rows) {
    const double x = px(r.ms), y = py(r.psnr_db);
    const char* colour = r.mode == "dvr" ? "#d62728" : "#1f77b4";
    const std::string label = r.view + " " + std::to_string(r.size) + " L" +
                              Format("%g", r.lod_bias) + " s" + Format("%g", r.step) + " B" +
                              Format("%.3g", r.brick_mb) + " " + r.frame_kind;
    if (r.frame_kind.rfind("refined", 0) == 0) {
      s << "<rect x=\"" << x - 4 << "\" y=\"" << y - 4 << "\" width=\"8\" height=\"8\" fill=\""
        << colour << "\"><title>" << SvgEscape(label) << "</title></rect>\n";
    } else {
      const bool cold = r.frame_kind == "cold";
      s << "<circle cx=\"" << x << "\" cy=\"" << y << "\" r=\"4\" fill=\""
        << (cold ? "white" : colour) << "\" stroke=\"" << colour << "\"><title>" << SvgEscape(label)
        << "</title></circle>\n";
    }
    s << "<text x=\"" << x + 6 << "\" y=\"" << y - 3 << "\" font-size=\"8\" fill=\"#444\">"
      << SvgEscape(label) << "</text>\n";
  }
  // Legend.
  const double lx = kLeft + 10, ly = kTop + 14;
  s << "<circle cx=\"" << lx << "\" cy=\"" << ly << "\" r=\"4\" fill=\"#d62728\"/>"
    << "<text x=\"" << lx + 8 << "\" y=\"" << ly + 4 << "\" font-size=\"11\">dvr</text>\n";
  s << "<circle cx=\"" << lx + 50 << "\" cy=\"" << ly << "\" r=\"4\" fill=\"#1f77b4\"/>"
    << "<text x=\"" << lx + 58 << "\" y=\"" << ly + 4 << "\" font-size=\"11\">mip</text>\n";
  s << "<circle cx=\"" << lx + 100 << "\" cy=\"" << ly << "\" r=\"4\" fill=\"white\" "
    << "stroke=\"black\"/><text x=\"" << lx + 108 << "\" y=\"" << ly + 4
    << "\" font-size=\"11\">cold full frame</text>\n";
  s << "<circle cx=\"" << lx + 210 << "\" cy=\"" << ly << "\" r=\"4\" fill=\"black\"/>"
    << "<text x=\"" << lx + 218 << "\" y=\"" << ly + 4
    << "\" font-size=\"11\">steady full frame</text>\n";
  s << "<rect x=\"" << lx + 326 << "\" y=\"" << ly - 4 << "\" width=\"8\" height=\"8\" "
    << "fill=\"black\"/><text x=\"" << lx + 340 << "\" y=\"" << ly + 4
    << "\" font-size=\"11\">refined (total)</text>\n";
  s << "</svg>\n";
  return s.str();
}

Status WriteText(const std::filesystem::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::trunc | std::ios::binary);
  out << text;
  out.close();
  if (!out) return InternalError("cannot write " + path.string());
  return Status::Ok();
}

// ---------------------------------------------------------------------------------------------

int RunBenchRender(std::span<const std::string> args) {
  const auto start = std::chrono::steady_clock::now();
  Flags flags(
      "octoscope bench render [INPUT] [options]",
      "Speed against error of the OpenCL renderer: renders fixed views (z, x, iso orthographic,\n"
      "one perspective) of INPUT (8/16-bit; default: the demo specimen, built in memory) over\n"
      "a sweep of settings, compares every image with the CPU reference renderer and measures\n"
      "the renderer against a plain dense OpenCL kernel and a hand-written multi-threaded C++\n"
      "loop. Writes DIR/render_bench.md\n"
      "(also printed) and DIR/render_bench.svg (speed vs error).");
  flags.SetPositionals("[INPUT]", 0, 1);
  flags.AddValue("demo", "SIZE",
                 "use the demo specimen of SIZE^3 voxels (1 µm isotropic unless --spacing)",
                 "512; 32 with --quick");
  flags.AddValue("channels", "N", "demo channels, 1..4", "3");
  flags.AddValue("embryo-percent", "P",
                 "how much of the demo's box the embryo spans per axis, 1..100 (small: sparse)",
                 "92");
  flags.AddValue("window-low", "PCT",
                 "each channel's window starts at this percentile of its voxels, 0..99\n"
                 "                            (sparse volumes: above the background noise)",
                 "60");
  flags.AddValue("out-dir", "DIR", "output directory", "out/bench-render");
  flags.AddValue("sizes", "LIST", "image sizes (first: the base size)", "256,512,1024");
  flags.AddValue("reference-size", "R",
                 "reference images at most R x R; larger images are compared on their central\n"
                 "                            R x R crop at full resolution",
                 "256; 24 with --quick");
  flags.AddValue("reference-step", "S", "step of the reference images, voxels", "0.5");
  flags.AddValue("brick", "N", "octree brick size, even", "64; 16 with --quick");
  flags.AddValue("threshold", "F", "LOSSY homogeneity threshold (fraction of each channel's range)",
                 "0: lossless, as octoscope build");
  flags.AddValue("repeats", "N", "frames timed for the headline ratios (median)", "3");
  flags.AddValue("device", "PREF", "OpenCL device: auto, gpu, cpu, N, P:D or a name", "auto");
  flags.AddSwitch("quick", "a tiny run (seconds): 32^3 demo, 32^2 images, 24^2 references");
  flags.AddSwitch("headline-only",
                  "measure only the settings the headline ratios need (iso view; large volumes)");
  flags.AddSwitch("json", "print the results as one JSON document instead of the table");
  AddVolumeFlags(flags);  // --spacing also applies to the demo.
  if (Status s = flags.Parse(args); !s.ok()) return Usage(s.message(), flags);
  if (flags.help_requested()) {
    std::printf("%s", flags.Help().c_str());
    return kExitOk;
  }
  const bool quick = flags.Has("quick");
  const bool json = flags.Has("json");
  auto demo_size = flags.GetInt("demo", quick ? 32 : 512, 8, 4096);
  if (!demo_size.ok()) return Usage(demo_size.status().message(), flags);
  auto channels = flags.GetInt("channels", 3, 1, io::SyntheticEmbryo::kMaxChannels);
  if (!channels.ok()) return Usage(channels.status().message(), flags);
  auto embryo_percent = flags.GetInt("embryo-percent", 92, 1, 100);
  if (!embryo_percent.ok()) return Usage(embryo_percent.status().message(), flags);
  auto window_low = flags.GetDouble("window-low", 60);
  if (!window_low.ok()) return Usage(window_low.status().message(), flags);
  if (!(*window_low >= 0 && *window_low <= 99))
    return Usage("--window-low must be in [0, 99]", flags);
  auto sizes = ParseSizes(flags.Get("sizes").value_or(quick ? "32" : "256,512,1024"));
  if (!sizes.ok()) return Usage(sizes.status().message(), flags);
  auto reference_size = flags.GetInt("reference-size", quick ? 24 : 256, 8, 4096);
  if (!reference_size.ok()) return Usage(reference_size.status().message(), flags);
  for (int size : *sizes) {
    if (size > *reference_size && (size - *reference_size) % 2 != 0) {
      return Usage("--sizes: " + std::to_string(size) + " - reference size must be even", flags);
    }
  }
  auto reference_step = flags.GetDouble("reference-step", 0.5);
  if (!reference_step.ok()) return Usage(reference_step.status().message(), flags);
  if (!(*reference_step >= render::kMinStepVoxels && *reference_step <= render::kMaxStepVoxels)) {
    return Usage("--reference-step must lie in [1/64, 64]", flags);
  }
  auto brick = flags.GetInt("brick", quick ? 16 : 64, 2, 256);
  if (!brick.ok() || *brick % 2 != 0)
    return Usage("--brick must be an even number in 2..256", flags);
  auto threshold = flags.GetDouble("threshold", 0.0);
  if (!threshold.ok()) return Usage(threshold.status().message(), flags);
  if (!(*threshold >= 0 && *threshold <= 1)) return Usage("--threshold must be in [0, 1]", flags);
  auto repeats = flags.GetInt("repeats", quick ? 1 : 3, 1, 100);
  if (!repeats.ok()) return Usage(repeats.status().message(), flags);
  const std::filesystem::path out_dir = flags.Get("out-dir").value_or("out/bench-render");
  // --spacing overrides INPUT's spacing, or the demo's 1 µm (anisotropic voxels take DVR's
  // general opacity correction: the serve demo's are 0.5 x 0.5 x 1 µm).
  auto open_options = VolumeOptionsFromFlags(flags);
  if (!open_options.ok()) return Usage(open_options.status().message(), flags);
  if (flags.positionals().empty()) {
    for (const char* name : {"series", "time", "level", "decode-threads"}) {
      if (flags.Get(name)) return Usage(std::string("--") + name + " needs an INPUT", flags);
    }
  }

  // 1. The volume, as stored values in RAM.
  std::unique_ptr<io::VolumeSource> source;
  std::string description;
  if (!flags.positionals().empty()) {
    auto opened = io::OpenVolume(flags.positionals()[0], *open_options);
    if (!opened.ok()) return Fail(opened.status().WithContext(flags.positionals()[0]).ToString());
    source = std::move(*opened);
    description = flags.positionals()[0];
    if (auto spacing = flags.Get("spacing")) description += " (--spacing " + *spacing + ")";
  } else {
    io::SyntheticEmbryoOptions demo;
    demo.size = {*demo_size, *demo_size, *demo_size};
    demo.channels = static_cast<int>(*channels);
    for (int a = 0; a < 3; ++a) demo.spacing_um[a] = open_options->spacing_um[a].value_or(1.0);
    demo.embryo_percent = static_cast<int>(*embryo_percent);
    auto embryo = io::SyntheticEmbryo::Create(demo);
    if (!embryo.ok()) return Usage(embryo.status().message(), flags);
    source = std::move(*embryo);
    const bool isotropic =
        demo.spacing_um[0] == 1 && demo.spacing_um[1] == 1 && demo.spacing_um[2] == 1;
    const std::string voxels = isotropic ? "1 µm isotropic"
                                         : Format("%g", demo.spacing_um[0]) + " x " +
                                               Format("%g", demo.spacing_um[1]) + " x " +
                                               Format("%g", demo.spacing_um[2]) + " µm voxels";
    description = "demo " + std::to_string(*demo_size) + "^3 x" + std::to_string(*channels) +
                  " uint16 (" + voxels + ", embryo " + std::to_string(*embryo_percent) +
                  " % of the box)";
  }
  std::fprintf(stderr, "bench: loading %s ...\n", description.c_str());
  auto loaded = LoadVolume(*source, description);
  if (!loaded.ok()) return Fail(loaded.status().ToString());
  source.reset();
  loaded->dvr = BenchParams(*loaded, RenderMode::kDvr, *window_low);
  loaded->mip = BenchParams(*loaded, RenderMode::kMip, *window_low);
  const render::Vec3 spacing = render::PhysicalSpacing(loaded->info);
  const render::Box3 box = render::PhysicalBounds(loaded->info.size, spacing);

  // 2. The device (before the slow steps: no device, no bench).
  const std::string preference = flags.Get("device").value_or("");
  auto device = render::ChooseDevice(preference == "auto" ? "" : preference);
  if (!device.ok()) return Fail("no OpenCL device: " + device.status().ToString());
  auto context = render::ComputeContext::Create(*device);
  if (!context.ok()) return Fail("no OpenCL device: " + context.status().ToString());
  render::ProgramCache programs(&*context);

  // 3. The octree, in memory.
  std::fprintf(stderr, "bench: building the octree ...\n");
  auto tree = BuildInMemory(*loaded, *brick, *threshold);
  if (!tree.ok()) return Fail(tree.status().ToString());
  const octree::OctreeStats tree_stats = tree->tree->stats();
  const uint64_t brick_bytes = tree->tree->geometry().brick_bytes();

  // 4. The reference images, once per (view, mode, size).
  const std::vector<Setting> sweep = BuildSweep(*sizes, flags.Has("headline-only"));
  std::vector<ReferenceKey> keys;
  for (const Setting& s : sweep) {
    ReferenceKey key{s.view, s.mode, s.size};
    if (std::find(keys.begin(), keys.end(), key) == keys.end()) keys.push_back(key);
  }
  std::fprintf(stderr, "bench: %zu reference images (<= %d^2, step %g) ...\n", keys.size(),
               static_cast<int>(*reference_size), *reference_step);
  std::map<ReferenceKey, RenderImage> references;
  {
    auto rendered = RenderReferences(*loaded->volume, *loaded, keys,
                                     static_cast<int>(*reference_size), *reference_step);
    if (!rendered.ok()) return Fail(rendered.status().ToString());
    references = std::move(*rendered);
  }

  // 5. The C++ loop gets its own copy of the voxels (the reference's is dropped: two at most).
  std::vector<std::vector<uint16_t>> voxels;
  for (int c = 0; c < loaded->channel_count(); ++c) {
    const std::span<const uint16_t> ch = loaded->channel(c);
    voxels.emplace_back(ch.begin(), ch.end());
  }
  // The plain dense kernel gets the voxels as one device buffer (bench/baseline/dense_kernel.h).
  std::unique_ptr<bench::DenseKernel> dense;
  {
    std::vector<std::span<const uint16_t>> channel_spans;
    for (const std::vector<uint16_t>& ch : voxels) channel_spans.emplace_back(ch);
    auto created =
        bench::DenseKernel::Create(&*context, &programs, loaded->info.size, spacing, channel_spans);
    if (!created.ok()) return Fail("plain dense kernel: " + created.status().ToString());
    dense = std::make_unique<bench::DenseKernel>(std::move(*created));
  }
  loaded->volume.reset();
  auto loop = bench::CpuRaycaster::Create(loaded->info.size, spacing, loaded->stored_type,
                                          std::move(voxels));
  if (!loop.ok()) return Fail(loop.status().ToString());

  // Large buffer: every brick of the tree (+ slack); small: an eighth of that (at least the
  // device octree's minimum slot count).
  const uint64_t min_bytes = brick_bytes * render::kMinBrickSlots;
  const uint64_t large = std::max(min_bytes * 2, tree_stats.pool_bytes + tree_stats.pool_bytes / 8);
  const uint64_t small = std::max(min_bytes, large / 8);
  Bench bench{&*context, &programs, tree->tree.get(), &*loaded, spacing, box,
              small,     large,     &references};

  // 6. The sweep.
  RenderBenchReport report;
  report.volume = description;
  report.device = device->ToString();
  report.reference_size = static_cast<int>(*reference_size);
  report.reference_step = *reference_step;
  std::vector<int> warmed;
  for (const Setting& s : sweep) {
    if (std::find(warmed.begin(), warmed.end(), s.size) == warmed.end()) {
      if (Status st = WarmUpSize(bench, s.size); !st.ok()) return Fail(st.ToString());
      warmed.push_back(s.size);
    }
    const size_t first = report.rows.size();
    if (Status st = MeasureSetting(bench, s, &report.rows); !st.ok()) {
      return Fail(st.WithContext(s.view + " " + std::string(render::RenderModeName(s.mode)) + " " +
                                 std::to_string(s.size))
                      .ToString());
    }
    std::fprintf(stderr,
                 "bench: %s %s %d² lod %g step %g brick %.0f MB: cold %.1f ms, %s %.1f ms "
                 "(%d frames), refined %.1f ms (%d passes)\n",
                 s.view.c_str(), std::string(render::RenderModeName(s.mode)).c_str(), s.size,
                 s.lod_bias, s.step, report.rows[first].brick_mb, report.rows[first].ms,
                 report.rows[first + 1].frame_kind.c_str(), report.rows[first + 1].ms,
                 report.rows[first + 1].passes, report.rows[first + 2].ms,
                 report.rows[first + 2].passes);
  }

  // 7. Headlines. (a) kernels vs the C++ loop at level 0, everything resident.
  std::ostringstream head;
  const int base = (*sizes)[0];
  head << "Volume: " << description << "; octree: " << tree_stats.nodes << " nodes, "
       << tree_stats.bricks << " bricks (" << Format("%.0f", tree_stats.pool_bytes / 1048576.0)
       << " MB), bricks of " << *brick << "³, threshold " << *threshold << ".\n";
  head << "Device: " << report.device << ". Brick buffers: small "
       << Format("%.0f", small / 1048576.0) << " MB, large " << Format("%.0f", large / 1048576.0)
       << " MB.\n";
  head << "Errors against the CPU reference renderer at step " << *reference_step
       << " (images larger than " << *reference_size << "² on their central " << *reference_size
       << "² crop); Msamples/s = channel samples per second of kernel time.\n\n";
  auto error_text = [](const ImageError& e) {
    return Format("%.1f", e.psnr) + " dB, max_err " + Format("%.4f", e.max_abs);
  };
  for (RenderMode mode : {RenderMode::kDvr, RenderMode::kMip}) {
    const std::string name(render::RenderModeName(mode));
    std::fprintf(stderr, "bench: octree renderer vs plain kernel vs C++ loop, %s ...\n",
                 name.c_str());
    auto k = MeasureKernelVsLoop(bench, *dense, *loop, mode, base, static_cast<int>(*repeats));
    if (!k.ok()) return Fail(k.status().WithContext("kernel vs loop " + name).ToString());
    const std::string where = "iso " + std::to_string(base) + "², step 1, level 0" +
                              (k->steady ? "" : " (NOT all resident)");
    // (a0) The octree and paging cost: per sample, same samples (skipping off).
    const double per_sample =
        k->dense.msamples > 0 ? k->octree_dense.msamples / k->dense.msamples : 0;
    report.headlines.push_back({"octree_vs_dense_kernel_msamples_" + name, per_sample, 0.6, true,
                                where + ", empty-space skipping off"});
    // (a1) What the product gives per frame: skipping on, against the plain kernel's frame.
    const double frame = k->octree.ms > 0 ? k->dense.ms / k->octree.ms : 0;
    report.headlines.push_back({"dense_kernel_vs_octree_frame_ms_" + name, frame, 3, true,
                                where + ", plain kernel frame ms / octree frame ms (skipping on)"});
    head << "- **(a0) " << name << ": octree renderer " << Format("%.1f", k->octree_dense.msamples)
         << " Msamples/s ÷ plain dense kernel " << Format("%.1f", k->dense.msamples)
         << " Msamples/s = " << Format("%.2f", per_sample) << "** (goal ≥ 0.6); "
         << (k->dense_packets
                 ? "the faster of the plain kernel's forms: eight rays per work item " +
                       Format("%.1f", k->dense_packet_msamples) + ", one ray " +
                       Format("%.1f", k->dense_single_msamples) + " Msamples/s"
                 : "the plain kernel casts one ray per work item (this device takes no "
                   "eight-ray packets): two runs " +
                       Format("%.1f", k->dense_packet_msamples) + ", " +
                       Format("%.1f", k->dense_single_msamples) + " Msamples/s")
         << "; " << where << ", skipping off: both take the same samples ("
         << k->octree_dense.samples << " vs " << k->dense.samples << "). Kernel "
         << Format("%.1f", k->octree_dense.ms_kernel) << " ms vs "
         << Format("%.1f", k->dense.ms_kernel) << " ms. Errors against the reference: "
         << "octree " << error_text(k->octree_dense.error) << "; plain kernel "
         << error_text(k->dense.error) << "; max |octree − plain| "
         << Format("%.4f", k->octree_vs_dense_max_err) << "."
         << (tree_stats.bricks < tree_stats.nodes
                 ? " NOT a like-for-like sample rate: " +
                       std::to_string(tree_stats.nodes - tree_stats.bricks) +
                       " nodes have no brick (homogeneous), and their samples read the node's "
                       "average instead of 8 voxels."
                 : std::string())
         << "\n";
    head << "- **(a1) " << name << ": plain kernel frame " << Format("%.1f", k->dense.ms)
         << " ms ÷ octree renderer frame " << Format("%.1f", k->octree.ms)
         << " ms = " << Format("%.2f", frame) << "×** (goal ≥ 3, sparse data); " << where
         << ", empty-space skipping on (" << k->octree.samples << " samples, " << k->octree.skipped
         << " skipped, " << Format("%.1f", k->octree.msamples) << " Msamples/s; octree "
         << error_text(k->octree.error) << ").\n";
    const double ratio = k->loop_msamples > 0 ? k->octree.msamples / k->loop_msamples : 0;
    report.headlines.push_back(
        {"kernel_vs_cpu_msamples_" + name, ratio, 0.7, true, where + ", skipping on"});
    report.headlines.push_back({"cpu_vs_kernel_ms_" + name,
                                k->octree.ms > 0 ? k->loop_ms / k->octree.ms : 0, 0, true,
                                "C++ loop ms / octree frame ms (includes empty-space skipping)"});
    report.headlines.push_back({"dense_kernel_vs_cpu_msamples_" + name,
                                k->loop_msamples > 0 ? k->dense.msamples / k->loop_msamples : 0, 0,
                                true, where + ", plain kernel / C++ loop"});
    head << "- (a) " << name << ": octree renderer " << Format("%.1f", k->octree.msamples)
         << " Msamples/s (skipping on) ÷ C++ loop " << Format("%.1f", k->loop_msamples)
         << " Msamples/s (" << k->loop_threads << " threads) = " << Format("%.2f", ratio)
         << "; plain kernel ÷ C++ loop = "
         << Format("%.2f", k->loop_msamples > 0 ? k->dense.msamples / k->loop_msamples : 0)
         << ". Frame: C++ loop " << Format("%.1f", k->loop_ms) << " ms (" << k->loop_samples
         << " samples), " << error_text(k->loop_error) << "; max |octree − loop| "
         << Format("%.4f", k->kernel_vs_loop_max_err) << ".\n";
  }
  // (b) refined MIP at the largest size vs one full-resolution C++ loop pass.
  {
    const int big = *std::max_element(sizes->begin(), sizes->end());
    const RenderBenchRow* refined = nullptr;
    for (const RenderBenchRow& r : report.rows) {
      if (r.view == "iso" && r.mode == "mip" && r.size == big && r.lod_bias == 0 && r.step == 1 &&
          r.brick_mb == large / 1048576.0 && r.frame_kind.rfind("refined", 0) == 0) {
        refined = &r;
      }
    }
    std::fprintf(stderr, "bench: C++ loop, mip %d² ...\n", big);
    auto camera = ViewCamera("iso", box, big);
    bench::CpuRaycastStats loop_stats;
    auto image = camera.ok()
                     ? loop->Render(*camera, loaded->Params(RenderMode::kMip, 1), 0, &loop_stats)
                     : Result<RenderImage>(camera.status());
    if (!image.ok()) return Fail(image.status().ToString());
    if (refined) {
      const double ratio = loop_stats.ms > 0 ? refined->ms / loop_stats.ms : 0;
      report.headlines.push_back({"refined_mip_vs_cpu_pass_" + std::to_string(big), ratio, 3, false,
                                  "iso, step 1, lod 0"});
      head << "- **(b) refined " << big << "² MIP " << Format("%.0f", refined->ms) << " ms ("
           << refined->passes << " passes) ÷ C++ loop full-resolution pass "
           << Format("%.0f", loop_stats.ms) << " ms = " << Format("%.2f", ratio)
           << "** (goal ≤ 3).\n";
    }
  }
  // (c) steady full-frame rate at the base size.
  {
    double worst = 1e300;
    std::string list;
    for (const RenderBenchRow& r : report.rows) {
      if (r.frame_kind == "steady" && r.size == base && r.lod_bias == 0 && r.step == 1 &&
          r.brick_mb == large / 1048576.0) {
        worst = std::min(worst, r.fps);
        list += (list.empty() ? "" : ", ") + r.view + " " + r.mode + " " + Format("%.1f", r.fps);
      }
    }
    if (worst < 1e300) {
      report.headlines.push_back(
          {"steady_full_frame_fps_" + std::to_string(base), worst, 10, true, list});
      head << "- **(c) steady full frame at " << base << "²: " << Format("%.1f", worst)
           << " fps at worst** (goal ≥ 10 on 512³): " << list << ".\n";
    }
  }
  // (c') interactive full frames (100 ms kernel-time target) at the base size: speed and error.
  {
    double worst = 1e300;
    std::string list;
    for (const RenderBenchRow& r : report.rows) {
      if (r.frame_kind == "interactive" && r.size == base && r.step == 1 &&
          r.brick_mb == large / 1048576.0) {
        worst = std::min(worst, r.fps);
        list += (list.empty() ? "" : ", ") + r.view + " " + r.mode + " " + Format("%.1f", r.fps) +
                " fps at bias " + Format("%.2f", r.lod_bias) + ", " + Format("%.1f", r.psnr_db) +
                " dB";
      }
    }
    if (worst < 1e300) {
      report.headlines.push_back(
          {"interactive_full_frame_fps_" + std::to_string(base), worst, 10, true, list});
      head << "- **(c') interactive full frames (target " << Format("%.0f", kInteractiveTargetMs)
           << " ms) at " << base << "²: " << Format("%.1f", worst)
           << " fps at worst** (goal ≥ 10): " << list << ".\n";
    }
  }
  report.seconds = MsSince(start) / 1000;
  head << "\nRun time " << Format("%.0f", report.seconds) << " s.\n";

  // 8. Output.
  std::error_code ec;
  std::filesystem::create_directories(out_dir, ec);
  if (ec) return Fail("cannot create " + out_dir.string() + ": " + ec.message());
  const std::string markdown = head.str() + "\n" + MarkdownTable(report.rows);
  if (Status s = WriteText(out_dir / "render_bench.md", markdown); !s.ok()) {
    return Fail(s.ToString());
  }
  if (Status s = WriteText(out_dir / "render_bench.svg",
                           SpeedErrorSvg(report.rows, "Speed vs error: " + description));
      !s.ok()) {
    return Fail(s.ToString());
  }
  if (json) {
    std::printf("%s\n", protocol::RenderBenchReportJson(report).c_str());
  } else {
    std::printf("%s", markdown.c_str());
  }
  return kExitOk;
}

}  // namespace

int RunBench(std::span<const std::string> args) {
  constexpr const char* kUsage =
      "usage: octoscope bench render|upload [INPUT] [options]\n\n"
      "Benchmarks. 'octoscope bench render --help' describes the renderer benchmark,\n"
      "'octoscope bench upload --help' the brick upload benchmark.\n";
  if (args.empty()) {
    std::fprintf(stderr, "%s", kUsage);
    return kExitUsage;
  }
  if (args[0] == "--help" || args[0] == "-h") {
    std::printf("%s", kUsage);
    return kExitOk;
  }
  if (args[0] == "render") return RunBenchRender(args.subspan(1));
  if (args[0] == "upload") return RunBenchUpload(args.subspan(1));
  std::fprintf(stderr, "octoscope bench: unknown benchmark '%s' (known: render, upload)\n",
               Printable(args[0]).c_str());
  return kExitUsage;
}

}  // namespace octoscope::app
