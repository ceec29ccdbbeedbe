// Device octree traversal and brick sampling (kernels/octree_sampling.cl, through the test
// kernels of kernels/sample_points.cl) against independent CPU computations: a real octree is
// built on the CPU, mirrored into a node buffer (octree::EncodeNode) and a brick buffer, sampled
// on the device at random positions and every level, and compared with
//   * a CPU walk of the octree by node KEY (Octree::GetNode, not the device's child pointers) and
//     double-precision trilinear interpolation in the node's brick (Octree::ReadBrick,
//     BrickGeometry::StoredSampleOffset in global level coordinates);
//   * at level 0 with threshold 0, trilinear interpolation of the SOURCE voxels (background
//     outside the volume), which is what the bricks and their aprons must reproduce.
// The device is never its own oracle.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <map>
#include <memory>
#include <numeric>
#include <random>
#include <span>
#include <vector>

#include "../../kernels/node_format.h"
#include "cl_test_env.h"
#include "octree/brick_geometry.h"
#include "octree/node_encoding.h"
#include "octree/octree.h"
#include "paging/memory_page_store.h"
#include "paging/page_cache.h"
#include "render/cl_handles.h"

namespace octoscope::render {
namespace {

using ::octoscope::render::testing::kTestBuildOptions;
using ::octoscope::render::testing::SharedClTestEnv;
using octree::Box;
using octree::BrickGeometry;
using octree::NodeKey;
using octree::NodeSnapshot;
using octree::Octree;
using octree::Vec3;

// The kernels' view of the format is the encoder's (node_format_check.cpp proves the rest).
static_assert(OCTO_NODE_WORDS(3) == octree::NodeWords(3));
static_assert(OCTO_NODE_IN_BUFFER_BIT == octree::kNodeInBufferBit);
static_assert(sizeof(OctoTreeGeometry) == 32);

struct Config {
  const char* name;
  Vec3 size;
  Vec3 brick;
  int channels;
  double threshold;          // Homogeneity threshold of the tree.
  double resident_fraction;  // Share of bricks put into the brick buffer (in_buffer).
};

std::ostream& operator<<(std::ostream& os, const Config& c) { return os << c.name; }

// A deterministic hash for noise voxels.
uint32_t Hash(int64_t x, int64_t y, int64_t z, int c) {
  uint32_t h = static_cast<uint32_t>(x * 73856093 ^ y * 19349663 ^ z * 83492791 ^ c * 2654435761u);
  h ^= h >> 13;
  h *= 0x5bd1e995u;
  h ^= h >> 15;
  return h;
}

// Three regions: noise (x < 1/3 of the width: every brick different), a constant block (x beyond,
// z < half: homogeneous nodes and pruned subtrees), a gradient elsewhere (bricks that a 5 %
// threshold prunes but threshold 0 keeps).
uint16_t SourceValue(const Vec3& size, int64_t x, int64_t y, int64_t z, int c) {
  if (3 * x < size[0]) return static_cast<uint16_t>(Hash(x, y, z, c) & 0xffffu);
  if (2 * z < size[2]) return static_cast<uint16_t>(1000 * (c + 1));
  return static_cast<uint16_t>(20000 + 90 * x + 37 * y + 11 * z + 5000 * c);
}

class OctreeSamplingTest : public ::testing::TestWithParam<Config> {
 protected:
  void SetUp() override {
    const Config& config = GetParam();
    BrickGeometry::Params params;
    params.volume_size = config.size;
    params.brick_size = config.brick;
    params.channels = config.channels;
    params.bytes_per_sample = 2;
    auto geometry = BrickGeometry::Create(params);
    ASSERT_TRUE(geometry.ok()) << geometry.status().ToString();
    octree::OctreeOptions options;
    options.brick_size = config.brick;
    options.homogeneity_threshold = config.threshold;
    for (int c = 0; c < config.channels; ++c) background_.push_back(static_cast<uint16_t>(7 + c));
    options.background = background_;
    store_ = std::make_unique<paging::MemoryPageStore>(geometry->brick_bytes() * 8);
    cache_ = std::make_unique<paging::PageCache>(store_.get(), uint64_t{256} << 20);
    auto tree = Octree::Create(*geometry, options, cache_.get());
    ASSERT_TRUE(tree.ok()) << tree.status().ToString();
    tree_ = std::move(*tree);
    const Box all{{0, 0, 0}, config.size};
    for (int c = 0; c < config.channels; ++c) {
      std::vector<uint16_t> data;
      data.reserve(all.VoxelCount());
      for (int64_t z = 0; z < config.size[2]; ++z)
        for (int64_t y = 0; y < config.size[1]; ++y)
          for (int64_t x = 0; x < config.size[0]; ++x)
            data.push_back(SourceValue(config.size, x, y, z, c));
      ASSERT_TRUE(tree_->Insert(c, all, std::as_bytes(std::span(data))).ok());
    }
    MirrorTree();
  }

  const BrickGeometry& geometry() const { return tree_->geometry(); }
  int channels() const { return geometry().channels(); }

  // Fills nodes_ / bricks_ the way the renderer's uploader will: every live node encoded at its
  // id, a random subset of bricks resident in shuffled slots (slot 0 holds a poison brick).
  void MirrorTree() {
    std::mt19937 rng(1234);
    std::vector<NodeSnapshot> live;
    std::vector<uint32_t> queue = {0};
    uint32_t max_group = 0;
    for (size_t i = 0; i < queue.size(); ++i) {
      auto node = tree_->GetNode(queue[i]);
      ASSERT_TRUE(node.has_value()) << queue[i];
      if (node->has_children()) {
        max_group = std::max(max_group, node->child_group);
        for (uint32_t o = 0; o < 8; ++o) queue.push_back(8 * node->child_group + o);
      }
      live.push_back(*node);
    }
    const size_t words = static_cast<size_t>(octree::NodeWords(channels()));
    nodes_.assign(8 * (size_t{max_group} + 1) * words, 0);
    std::vector<uint32_t> with_brick;
    for (const NodeSnapshot& n : live) {
      if (n.has_brick()) with_brick.push_back(n.id);
    }
    std::shuffle(with_brick.begin(), with_brick.end(), rng);
    std::bernoulli_distribution keep(GetParam().resident_fraction);
    const size_t brick_samples = geometry().brick_samples();
    bricks_.assign(brick_samples, 0xdeadu);  // Slot 0: poison, never referenced.
    for (uint32_t id : with_brick) {
      if (!keep(rng)) continue;
      const uint32_t slot = static_cast<uint32_t>(bricks_.size() / brick_samples);
      slot_of_[id] = slot;
      bricks_.resize(bricks_.size() + brick_samples);
      ASSERT_TRUE(
          tree_->ReadBrick(id, std::as_writable_bytes(std::span(bricks_).last(brick_samples)))
              .ok());
    }
    for (const NodeSnapshot& n : live) {
      octree::DeviceNode d;
      d.has_brick = n.has_brick();
      d.in_buffer = slot_of_.count(n.id) != 0;
      d.brick_slot = d.in_buffer ? slot_of_.at(n.id) : 0;
      d.child_group = n.child_group;
      for (const auto& s : n.channels) d.averages.push_back(octree::QuantizeAverage(s.avg, 2));
      ASSERT_TRUE(octree::WriteNode(nodes_, n.id, d).ok());
      if (n.has_brick()) ++brick_nodes_;
      if (!n.has_brick() && !n.is_virtual) ++homogeneous_nodes_;
      if (n.has_brick() && !d.in_buffer) ++absent_bricks_;
    }
    node_count_ = live.size();
  }

  OctoTreeGeometry DeviceGeometry() const {
    OctoTreeGeometry g{};
    for (int a = 0; a < 3; ++a) {
      g.volume_size[a] = static_cast<int>(geometry().volume_size()[a]);
      g.brick_size[a] = static_cast<int>(geometry().brick_size()[a]);
    }
    g.root_level = geometry().root_level();
    g.channels = channels();
    return g;
  }

  // Positions: mostly inside the volume, some in the virtual extension of the node grid, some on
  // exact voxel and brick boundaries.
  std::vector<std::array<float, 4>> Positions(int count, uint32_t seed) const {
    std::mt19937 rng(seed);
    const Vec3& size = geometry().volume_size();
    const Vec3& bs = geometry().brick_size();
    std::vector<std::array<float, 4>> out;
    for (int i = 0; i < count; ++i) {
      std::array<float, 4> p{0, 0, 0, 0};
      for (int a = 0; a < 3; ++a) {
        const double grid = static_cast<double>(bs[a] << geometry().root_level());
        const int kind = i % 10;
        double v;
        if (kind == 0) {
          v = std::uniform_real_distribution<double>(0, grid)(rng);  // Anywhere in the grid.
        } else if (kind == 1) {
          // A brick boundary of some level (exactly representable).
          const int level = std::uniform_int_distribution<int>(0, geometry().root_level())(rng);
          const int64_t step = bs[a] << level;
          v = static_cast<double>(
              step * std::uniform_int_distribution<int64_t>(0, (size[a] - 1) / step)(rng));
        } else if (kind == 2) {
          v = std::uniform_int_distribution<int64_t>(0, size[a] - 1)(rng) + 0.5;  // Voxel centre.
        } else {
          v = std::uniform_real_distribution<double>(0, static_cast<double>(size[a]))(rng);
        }
        p[a] = static_cast<float>(v);
        if (p[a] >= grid) p[a] = std::nextafter(static_cast<float>(grid), 0.0f);
      }
      out.push_back(p);
    }
    return out;
  }

  struct Expected {
    uint32_t used = 0, wanted = 0;
    int used_level = 0, wanted_level = 0;
    std::vector<double> values;
  };

  // The CPU reference: walk by node key from the root towards `level`; use the deepest node
  // whose brick is resident or that has no brick (else the root's averages).
  Expected Reference(const std::array<float, 4>& position, int level) {
    const int root = geometry().root_level();
    const int target = std::clamp(level, 0, root);
    const std::array<double, 3> p{position[0], position[1], position[2]};
    auto key_at = [&](int l) {
      Vec3 voxel;
      for (int a = 0; a < 3; ++a) voxel[a] = static_cast<int64_t>(std::floor(std::ldexp(p[a], -l)));
      return geometry().NodeContaining(l, voxel);
    };
    std::optional<NodeSnapshot> used = tree_->GetNode(geometry().RootKey());
    std::optional<NodeSnapshot> wanted = used;
    for (int l = root - 1; l >= target; --l) {
      auto node = tree_->GetNode(key_at(l));
      if (!node) break;
      wanted = node;
      if (!node->has_brick() || slot_of_.count(node->id) != 0) used = node;
    }
    Expected e;
    e.used = used->id;
    e.used_level = used->key.level;
    e.wanted = wanted->id;
    e.wanted_level = wanted->key.level;
    const bool resident = slot_of_.count(used->id) != 0;
    for (int c = 0; c < channels(); ++c) {
      if (!resident) {
        e.values.push_back(octree::QuantizeAverage(used->channels[c].avg, 2));
        continue;
      }
      const std::vector<uint16_t>& brick = Brick(used->id);
      const int l = used->key.level;
      double sum = 0;
      std::array<int64_t, 3> v0;
      std::array<double, 3> f;
      for (int a = 0; a < 3; ++a) {
        const double t = std::ldexp(p[a], -l) - 0.5;  // Level-l voxel centres are integers.
        v0[a] = static_cast<int64_t>(std::floor(t));
        f[a] = t - std::floor(t);
      }
      for (int corner = 0; corner < 8; ++corner) {
        Vec3 v;
        double w = 1;
        for (int a = 0; a < 3; ++a) {
          const int bit = (corner >> a) & 1;
          v[a] = v0[a] + bit;
          w *= bit ? f[a] : 1 - f[a];
        }
        if (w == 0) continue;
        EXPECT_TRUE(geometry().StoredBox(used->key).Contains(v));
        sum += w * brick[geometry().StoredSampleOffset(used->key, v, c)];
      }
      e.values.push_back(sum);
    }
    return e;
  }

  // Trilinear interpolation of the source volume at level 0, background outside it.
  double SourceTrilinear(const std::array<float, 4>& p, int c) const {
    const Vec3& size = geometry().volume_size();
    std::array<int64_t, 3> v0;
    std::array<double, 3> f;
    for (int a = 0; a < 3; ++a) {
      const double t = static_cast<double>(p[a]) - 0.5;
      v0[a] = static_cast<int64_t>(std::floor(t));
      f[a] = t - std::floor(t);
    }
    double sum = 0;
    for (int corner = 0; corner < 8; ++corner) {
      Vec3 v;
      double w = 1;
      bool inside = true;
      for (int a = 0; a < 3; ++a) {
        const int bit = (corner >> a) & 1;
        v[a] = v0[a] + bit;
        w *= bit ? f[a] : 1 - f[a];
        inside = inside && v[a] >= 0 && v[a] < size[a];
      }
      sum += w * (inside ? SourceValue(size, v[0], v[1], v[2], c) : background_[c]);
    }
    return sum;
  }

  const std::vector<uint16_t>& Brick(uint32_t id) {
    auto [it, inserted] = brick_cache_.try_emplace(id);
    if (inserted) {
      it->second.resize(geometry().brick_samples());
      EXPECT_TRUE(tree_->ReadBrick(id, std::as_writable_bytes(std::span(it->second))).ok());
    }
    return it->second;
  }

  struct DeviceResult {
    std::vector<float> values;                  // count * channels.
    std::vector<std::array<uint32_t, 4>> info;  // used, used level, wanted, wanted level.
  };

  // Runs SamplePoints on the device.
  DeviceResult Sample(const std::vector<std::array<float, 4>>& positions, int level) {
    const testing::ClTestEnv& env = SharedClTestEnv();
    const ComputeContext& cc = *env.context;
    DeviceResult r;
    auto kernel = env.programs->CreateKernel("sample_points.cl", "SamplePoints", kTestBuildOptions);
    EXPECT_TRUE(kernel.ok()) << kernel.status().ToString();
    if (!kernel.ok()) return r;
    auto nodes = cc.CreateBuffer(CL_MEM_READ_ONLY, nodes_.size() * 4, nodes_.data());
    auto bricks = cc.CreateBuffer(CL_MEM_READ_ONLY, bricks_.size() * 2, bricks_.data());
    auto pos = cc.CreateBuffer(CL_MEM_READ_ONLY, positions.size() * 16, positions.data());
    const size_t outputs = positions.size() * static_cast<size_t>(channels());
    auto out = cc.CreateBuffer(CL_MEM_WRITE_ONLY, outputs * 4);
    auto info = cc.CreateBuffer(CL_MEM_WRITE_ONLY, positions.size() * 16);
    for (auto* b : {&nodes, &bricks, &pos, &out, &info}) {
      EXPECT_TRUE(b->ok()) << b->status().ToString();
      if (!b->ok()) return r;
    }
    const Status set = SetKernelArgs(kernel->get(), *nodes, *bricks, DeviceGeometry(), *pos,
                                     static_cast<cl_uint>(positions.size()),
                                     static_cast<cl_int>(level), *out, *info);
    EXPECT_TRUE(set.ok()) << set.ToString();
    EXPECT_TRUE(cc.EnqueueKernel1D(kernel->get(), positions.size()).ok());
    r.values.resize(outputs);
    r.info.resize(positions.size());
    EXPECT_TRUE(cc.ReadBuffer(*out, 0, outputs * 4, r.values.data()).ok());
    EXPECT_TRUE(cc.ReadBuffer(*info, 0, positions.size() * 16, r.info.data()).ok());
    return r;
  }

  std::vector<uint16_t> background_;
  std::unique_ptr<paging::MemoryPageStore> store_;
  std::unique_ptr<paging::PageCache> cache_;
  std::unique_ptr<Octree> tree_;
  std::vector<uint32_t> nodes_;
  std::vector<uint16_t> bricks_;
  std::map<uint32_t, uint32_t> slot_of_;  // Node id -> brick slot, for resident bricks.
  std::map<uint32_t, std::vector<uint16_t>> brick_cache_;
  size_t node_count_ = 0;
  int brick_nodes_ = 0;
  int homogeneous_nodes_ = 0;
  int absent_bricks_ = 0;
};

// Float positions and float interpolation on the device against double on the CPU: neighbouring
// noise voxels differ by thousands, so a wrong voxel, half-voxel shift or wrong channel is far
// outside this tolerance.
constexpr double kTolerance = 1.0;

TEST_P(OctreeSamplingTest, TheTreeExercisesEveryKindOfNode) {
  // Not a device test: guards the configurations so the comparisons below cover bricks,
  // homogeneous nodes and (where configured) non-resident bricks.
  EXPECT_GT(brick_nodes_, 10);
  EXPECT_GT(homogeneous_nodes_, 0);
  if (GetParam().resident_fraction < 1) {
    EXPECT_GT(absent_bricks_, 0);
  }
  EXPECT_GT(geometry().root_level(), 1);
}

TEST_P(OctreeSamplingTest, DeviceDecodesEveryNodeLikeTheHost) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  const testing::ClTestEnv& env = SharedClTestEnv();
  const ComputeContext& cc = *env.context;
  auto kernel = env.programs->CreateKernel("sample_points.cl", "DecodeNodes", kTestBuildOptions);
  ASSERT_TRUE(kernel.ok()) << kernel.status().ToString();
  const size_t words = static_cast<size_t>(octree::NodeWords(channels()));
  const size_t count = nodes_.size() / words;
  const size_t per_node = 4 + static_cast<size_t>(channels());
  auto nodes = cc.CreateBuffer(CL_MEM_READ_ONLY, nodes_.size() * 4, nodes_.data());
  auto out = cc.CreateBuffer(CL_MEM_WRITE_ONLY, count * per_node * 4);
  ASSERT_TRUE(nodes.ok() && out.ok());
  ASSERT_TRUE(
      SetKernelArgs(kernel->get(), *nodes, DeviceGeometry(), static_cast<cl_uint>(count), *out)
          .ok());
  ASSERT_TRUE(cc.EnqueueKernel1D(kernel->get(), count).ok());
  std::vector<uint32_t> decoded(count * per_node);
  ASSERT_TRUE(cc.ReadBuffer(*out, 0, decoded.size() * 4, decoded.data()).ok());
  for (size_t n = 0; n < count; ++n) {
    const octree::DeviceNode host =
        octree::DecodeNode(std::span(nodes_).subspan(n * words, words), channels());
    const uint32_t* d = &decoded[n * per_node];
    ASSERT_EQ(d[0], host.in_buffer ? 1u : 0u) << "node " << n;
    ASSERT_EQ(d[1], host.has_brick ? 1u : 0u) << "node " << n;
    ASSERT_EQ(d[2], host.child_group) << "node " << n;
    ASSERT_EQ(d[3], host.brick_slot) << "node " << n;
    for (int c = 0; c < channels(); ++c) ASSERT_EQ(d[4 + c], host.averages[c]) << "node " << n;
  }
}

TEST_P(OctreeSamplingTest, MatchesCpuSamplingFromTheOctreeAtEveryLevel) {
  OCTO_REQUIRE_OPENCL_DEVICE();
  const int root = geometry().root_level();
  const auto positions = Positions(3000, 77);
  for (int level = 0; level <= root + 1; ++level) {
    SCOPED_TRACE("level " + std::to_string(level));
    const DeviceResult r = Sample(positions, level);
    ASSERT_EQ(r.info.size(), positions.size());
    int mismatches = 0;
    int fallbacks = 0;
    for (size_t i = 0; i < positions.size() && mismatches < 10; ++i) {
      const auto& p = positions[i];
      const Expected e = Reference(p, level);
      const std::string where = "position (" + std::to_string(p[0]) + ", " + std::to_string(p[1]) +
                                ", " + std::to_string(p[2]) + ")";
      if (e.used != e.wanted) ++fallbacks;
      EXPECT_EQ(r.info[i][0], e.used) << where;
      EXPECT_EQ(static_cast<int>(r.info[i][1]), e.used_level) << where;
      EXPECT_EQ(r.info[i][2], e.wanted) << where;
      EXPECT_EQ(static_cast<int>(r.info[i][3]), e.wanted_level) << where;
      for (int c = 0; c < channels(); ++c) {
        const double got = r.values[i * static_cast<size_t>(channels()) + static_cast<size_t>(c)];
        if (std::abs(got - e.values[c]) > kTolerance) {
          ++mismatches;
          ADD_FAILURE() << where << " channel " << c << ": device " << got << ", CPU "
                        << e.values[c] << " (node " << e.used << " level " << e.used_level << ")";
        }
      }
    }
    EXPECT_EQ(mismatches, 0);
    // With absent bricks some positions must actually have exercised the fallback.
    if (GetParam().resident_fraction < 1 && level == 0) {
      EXPECT_GT(fallbacks, 0);
    }
  }
}

TEST_P(OctreeSamplingTest, LevelZeroReproducesTrilinearInterpolationOfTheSource) {
  if (GetParam().threshold != 0 || GetParam().resident_fraction != 1) {
    GTEST_SKIP() << "only a lossless, fully resident tree reproduces the source exactly";
  }
  OCTO_REQUIRE_OPENCL_DEVICE();
  const auto positions = Positions(4000, 99);
  const DeviceResult r = Sample(positions, 0);
  ASSERT_EQ(r.info.size(), positions.size());
  const Vec3& size = geometry().volume_size();
  int mismatches = 0;
  int from_bricks = 0;
  for (size_t i = 0; i < positions.size() && mismatches < 10; ++i) {
    const auto& p = positions[i];
    const auto node = tree_->GetNode(r.info[i][0]);
    ASSERT_TRUE(node.has_value());
    const bool inside = p[0] < size[0] && p[1] < size[1] && p[2] < size[2];
    for (int c = 0; c < channels(); ++c) {
      const double got = r.values[i * static_cast<size_t>(channels()) + static_cast<size_t>(c)];
      double expected;
      if (node->has_brick()) {
        // A brick is only ever used at level 0 here (threshold 0 keeps every varying leaf).
        EXPECT_EQ(r.info[i][1], 0u);
        expected = SourceTrilinear(p, c);
      } else if (inside) {
        // A homogeneous node at threshold 0 is exactly constant: the source voxel under p.
        expected = SourceValue(size, static_cast<int64_t>(p[0]), static_cast<int64_t>(p[1]),
                               static_cast<int64_t>(p[2]), c);
      } else if (node->is_virtual) {
        expected = background_[c];  // A node without any valid voxel shows the background.
      } else {
        // Outside the volume in a partly valid homogeneous node: its average stands for its
        // valid voxels; the virtual ones have no source value to compare with.
        continue;
      }
      if (std::abs(got - expected) > kTolerance) {
        ++mismatches;
        ADD_FAILURE() << "position (" << p[0] << ", " << p[1] << ", " << p[2] << ") channel " << c
                      << ": device " << got << ", source " << expected;
      }
    }
    if (node->has_brick()) ++from_bricks;
  }
  EXPECT_EQ(mismatches, 0);
  EXPECT_GT(from_bricks, static_cast<int>(positions.size()) / 4);
}

INSTANTIATE_TEST_SUITE_P(
    Configs, OctreeSamplingTest,
    ::testing::Values(
        // 3 channels, anisotropic bricks, a volume that is no multiple of them, lossless.
        Config{"ThreeChannelsLossless", {45, 38, 29}, {8, 6, 4}, 3, 0.0, 1.0},
        // 1 channel, cubic bricks, deeper tree (root level 4), lossless.
        Config{"OneChannelDeep", {17, 9, 33}, {4, 4, 2}, 1, 0.0, 1.0},
        // 2 channels, 5 % threshold (approximate averages), 60 % of bricks resident.
        Config{"TwoChannelsPrunedPartlyResident", {40, 24, 20}, {4, 4, 4}, 2, 0.05, 0.6}),
    [](const ::testing::TestParamInfo<Config>& info) { return std::string(info.param.name); });

}  // namespace
}  // namespace octoscope::render
