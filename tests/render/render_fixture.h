// Test scenes for the renderer: a multi-channel volume held twice — as an in-memory octree (the
// renderer's input) and as a ReferenceVolume (the CPU reference renderer's input) — built from
// the same voxel arrays, so a GPU image can be compared with the reference image of the same data.
//
// Thread safety: a RenderScene is used by one test thread; its Octree has its own contract.
#ifndef OCTOSCOPE_TESTS_RENDER_RENDER_FIXTURE_H_
#define OCTOSCOPE_TESTS_RENDER_RENDER_FIXTURE_H_

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <functional>
#include <memory>
#include <span>
#include <utility>
#include <vector>

#include "octree/brick_geometry.h"
#include "octree/octree.h"
#include "paging/memory_page_store.h"
#include "paging/page_cache.h"
#include "render/reference_renderer.h"
#include "util/result.h"
#include "volume/data_type.h"

namespace octoscope::render::testing {

struct SceneSpec {
  std::array<int64_t, 3> size{32, 32, 32};
  Vec3 spacing{1, 1, 1};
  octree::Vec3 brick{16, 16, 16};
  int channels = 1;
  volume::DataType stored_type = volume::DataType::kUint16;
  double threshold = 0;  // Homogeneity threshold (fraction of the type's range).
  // Stored value of channel c at voxel (x, y, z); must be <= the type's maximum.
  std::function<uint16_t(int c, int64_t x, int64_t y, int64_t z)> value =
      [](int, int64_t, int64_t, int64_t) -> uint16_t { return 0; };
  // Block depth (planes) of the inserts; 0 = the whole volume at once per channel.
  int64_t insert_planes = 0;
  // Bytes per page of the brick pool's store; 0 = max(8 bricks, 1 MiB).
  uint64_t page_bytes = 0;
};

struct RenderScene {
  std::unique_ptr<paging::MemoryPageStore> store;
  std::unique_ptr<paging::PageCache> cache;
  std::unique_ptr<octree::Octree> tree;
  std::vector<std::vector<uint16_t>> voxels;  // Per channel, x fastest.
  SceneSpec spec;

  // The same voxels as a ReferenceVolume.
  Result<ReferenceVolume> Reference() const {
    return ReferenceVolume::FromStored(spec.size, spec.spacing, spec.stored_type, voxels);
  }
  // Inserts planes [z0, z1) of every channel (for incremental-build tests).
  Status InsertPlanes(int64_t z0, int64_t z1) {
    const auto& n = spec.size;
    const size_t plane = static_cast<size_t>(n[0] * n[1]);
    const int bytes = spec.stored_type == volume::DataType::kUint8 ? 1 : 2;
    for (int c = 0; c < spec.channels; ++c) {
      const uint16_t* first = voxels[c].data() + plane * static_cast<size_t>(z0);
      const size_t count = plane * static_cast<size_t>(z1 - z0);
      std::vector<std::byte> data(count * bytes);
      if (bytes == 1) {
        for (size_t i = 0; i < count; ++i) data[i] = static_cast<std::byte>(first[i]);
      } else {
        std::memcpy(data.data(), first, count * 2);
      }
      const octree::Box box{{0, 0, z0}, {n[0], n[1], z1}};
      OCTO_RETURN_IF_ERROR(tree->Insert(c, box, data));
    }
    return Status::Ok();
  }
};

// Creates the scene; with `insert` false the octree stays empty (InsertPlanes fills it).
inline Result<std::unique_ptr<RenderScene>> MakeRenderScene(const SceneSpec& spec,
                                                            bool insert = true) {
  auto scene = std::make_unique<RenderScene>();
  scene->spec = spec;
  octree::BrickGeometry::Params params;
  params.volume_size = {spec.size[0], spec.size[1], spec.size[2]};
  params.brick_size = spec.brick;
  params.channels = spec.channels;
  params.bytes_per_sample = spec.stored_type == volume::DataType::kUint8 ? 1 : 2;
  OCTO_ASSIGN_OR_RETURN(octree::BrickGeometry geometry, octree::BrickGeometry::Create(params));
  octree::OctreeOptions options;
  options.brick_size = spec.brick;
  options.homogeneity_threshold = spec.threshold;
  scene->store = std::make_unique<paging::MemoryPageStore>(
      spec.page_bytes != 0 ? spec.page_bytes
                           : std::max<uint64_t>(geometry.brick_bytes() * 8, uint64_t{1} << 20));
  scene->cache = std::make_unique<paging::PageCache>(scene->store.get(), uint64_t{1} << 30);
  OCTO_ASSIGN_OR_RETURN(scene->tree, octree::Octree::Create(geometry, options, scene->cache.get()));
  const auto& n = spec.size;
  scene->voxels.assign(spec.channels,
                       std::vector<uint16_t>(static_cast<size_t>(n[0] * n[1] * n[2])));
  for (int c = 0; c < spec.channels; ++c) {
    size_t i = 0;
    for (int64_t z = 0; z < n[2]; ++z)
      for (int64_t y = 0; y < n[1]; ++y)
        for (int64_t x = 0; x < n[0]; ++x) scene->voxels[c][i++] = spec.value(c, x, y, z);
  }
  if (insert) {
    const int64_t step = spec.insert_planes > 0 ? spec.insert_planes : n[2];
    for (int64_t z = 0; z < n[2]; z += step) {
      OCTO_RETURN_IF_ERROR(scene->InsertPlanes(z, std::min(n[2], z + step)));
    }
  }
  return scene;
}

// Image comparison: the largest absolute difference over all pixels and components, and the
// PSNR (dB, peak 1) over RGB. REQUIRES: equal sizes.
struct ImageDiff {
  double max_abs = 0;
  double psnr = 0;
  int worst_x = 0, worst_y = 0;
};
inline ImageDiff CompareImages(const RenderImage& a, const RenderImage& b) {
  ImageDiff d;
  double sum_sq = 0;
  size_t n = 0;
  for (size_t i = 0; i < a.rgba.size() && i < b.rgba.size(); ++i) {
    const double e = std::abs(static_cast<double>(a.rgba[i]) - b.rgba[i]);
    if (!(e <= d.max_abs)) {
      d.max_abs = std::isnan(e) ? INFINITY : e;
      d.worst_x = static_cast<int>((i / 4) % static_cast<size_t>(a.width));
      d.worst_y = static_cast<int>((i / 4) / static_cast<size_t>(a.width));
    }
    if (i % 4 != 3) {
      sum_sq += e * e;
      ++n;
    }
  }
  const double mse = n > 0 ? sum_sq / static_cast<double>(n) : 0;
  d.psnr = mse > 0 ? 10 * std::log10(1.0 / mse) : 200;
  return d;
}

}  // namespace octoscope::render::testing

#endif  // OCTOSCOPE_TESTS_RENDER_RENDER_FIXTURE_H_
