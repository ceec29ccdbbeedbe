#include "io/synthetic_embryo.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>
#include <utility>

namespace octoscope::io {
namespace {

// Geometry is computed in fixed point: positions in 1/16 voxel ("sub-units"), normalised embryo
// coordinates in 1/kUnit. Only integer arithmetic (and sqrt of exact integers, corrected to the
// exact floor) is used, so results cannot depend on the platform's floating point or libm.
constexpr int64_t kSub = 16;
constexpr int64_t kUnit = 4096;

// The nucleus cell edge is kEdgeFraction/100000 of the largest extent: a cube holds about 1200
// nuclei (0.4077 * cube volume / edge^3), a 256x256x128 box about 600.
constexpr int64_t kEdgeFraction = 6977;
constexpr int64_t kMinEdge = 6 * kSub;  // Small volumes get fewer, not smaller, nuclei.
// Width of the soft embryo edge (sub-units; a power of two so the blend is a shift).
constexpr int64_t kEdgeRamp = 2 * kSub;

// Nucleus profile: flat out to 0.70 of its radius, smooth fall to zero at 1.25 radii.
constexpr int64_t kProfileFlat = 717;                       // 0.70 * 1024.
constexpr int64_t kProfileEnd = 1280;                       // 1.25 * 1024.
constexpr int64_t kProfileCut = kProfileEnd * kProfileEnd;  // q bound, q = (d/r)^2 * 2^20.

// Per channel: background (camera offset), autofluorescence inside the embryo.
constexpr int32_t kBackground[4] = {110, 118, 104, 112};
constexpr int32_t kAutofluorescence[4] = {70, 45, 60, 30};
constexpr int32_t kMembraneBrightness = 1400;
constexpr int32_t kSurfaceBrightness = 1800;

constexpr const char* kChannelNames[4] = {"nuclei", "membranes", "spots", "reporter"};
constexpr volume::Rgba kChannelColors[4] = {
    {0, 160, 255, 255}, {0, 255, 0, 255}, {255, 0, 255, 255}, {255, 200, 0, 255}};

// Tags keep the hash streams of different purposes independent.
enum Tag : uint64_t { kTagNucleus = 1, kTagSpot, kTagReporter, kTagNoise };

// splitmix64's finaliser: a strong 64-bit mixer.
uint64_t Mix(uint64_t z) {
  z += 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

uint64_t Hash(uint64_t seed, uint64_t tag, uint64_t a, uint64_t b = 0, uint64_t c = 0) {
  uint64_t h = Mix(seed ^ Mix(tag));
  h = Mix(h ^ a);
  h = Mix(h ^ (b * 0xD1B54A32D192ED03ull));
  return Mix(h ^ (c * 0x8CB92BA72F3D8DD7ull));
}

// A value in [lo, hi] taken from 10 bits of `bits` starting at `shift`.
int64_t Pick(uint64_t bits, int shift, int64_t lo, int64_t hi) {
  return lo + (hi - lo) * static_cast<int64_t>((bits >> shift) & 1023) / 1023;
}

// floor(sqrt(v)), exact. The double sqrt is only a first guess: the integer correction makes the
// result independent of rounding.
uint64_t IntSqrt(uint64_t v) {
  uint64_t r = static_cast<uint64_t>(std::sqrt(static_cast<double>(v)));
  while (r > 0 && r * r > v) --r;
  while ((r + 1) * (r + 1) <= v) ++r;
  return r;
}

int64_t FloorDiv(int64_t a, int64_t b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }

// t in [0, 1024] -> smoothstep(t) in [0, 1024].
int64_t Smoothstep1024(int64_t t) { return t * t * (3 * 1024 - 2 * t) / (1024 * 1024); }

// An approximately normal deviate (sum of four uniforms): mean 0, standard deviation ~37837.
constexpr int64_t kGaussSigma = 37837;
int64_t Gaussian(uint64_t h) {
  return static_cast<int64_t>((h & 0xFFFF) + ((h >> 16) & 0xFFFF) + ((h >> 32) & 0xFFFF) +
                              (h >> 48)) -
         131070;
}

int64_t Pos(int64_t voxel) { return voxel * kSub + kSub / 2; }

}  // namespace

// A regular grid of cells over the volume, each holding at most one item (nucleus or spot).
// Invariants: cells[a] >= 1; item.size() == cells[0]*cells[1]*cells[2].
struct SyntheticEmbryo::Grid {
  std::array<int64_t, 3> cells{1, 1, 1};
  std::array<int64_t, 3> extent{1, 1, 1};  // Sub-units.
  std::vector<int32_t> item;               // -1: empty. x fastest.

  Grid(const std::array<int64_t, 3>& size, int64_t edge) {
    for (int a = 0; a < 3; ++a) {
      extent[a] = size[a] * kSub;
      cells[a] = std::max<int64_t>(1, (extent[a] + edge / 2) / edge);
    }
    item.assign(cells[0] * cells[1] * cells[2], -1);
  }
  int64_t CellOf(int axis, int64_t pos) const {
    return std::clamp<int64_t>(pos * cells[axis] / extent[axis], 0, cells[axis] - 1);
  }
  int64_t Lo(int axis, int64_t i) const { return i * extent[axis] / cells[axis]; }
  int32_t& At(int64_t i, int64_t j, int64_t k) { return item[(k * cells[1] + j) * cells[0] + i]; }
  int32_t At(int64_t i, int64_t j, int64_t k) const {
    return item[(k * cells[1] + j) * cells[0] + i];
  }
};

struct SyntheticEmbryo::Nucleus {
  std::array<int64_t, 3> centre;      // Sub-units.
  std::array<int64_t, 3> radius;      // Per-axis radius, sub-units, >= 8.
  std::array<int64_t, 3> inv_radius;  // 2^24 / radius.
  int32_t brightness;                 // Channel 0 peak above background.
  int32_t reporter_brightness;        // Channel 3 peak; 0 when the reporter is off.
};

struct SyntheticEmbryo::Spot {
  std::array<int64_t, 3> centre;  // Sub-units.
  int64_t radius;                 // Sub-units; the spot ends there.
  int32_t brightness;
};

struct SyntheticEmbryo::RowScratch {
  std::vector<int32_t> signal;  // Per x: structure signal above background.
  // Membrane candidates of one row, grouped by x cell: candidates of cell i are
  // [cell_start[i], cell_start[i+1]).
  std::vector<int64_t> cand_x, cand_pre;
  std::vector<int32_t> cand_index;
  std::vector<int64_t> cell_start;
  // The same, merged over each x cell and its two neighbours and sorted by cand_pre.
  std::vector<int64_t> merged_x, merged_pre;
  std::vector<int32_t> merged_index;
  std::vector<int64_t> merged_start;
  std::vector<int64_t> order;
};

SyntheticEmbryo::SyntheticEmbryo() = default;
SyntheticEmbryo::~SyntheticEmbryo() = default;

int SyntheticEmbryo::nucleus_count() const { return present_nuclei_; }
int SyntheticEmbryo::spot_count() const { return static_cast<int>(spots_.size()); }

Result<std::unique_ptr<SyntheticEmbryo>> SyntheticEmbryo::Create(
    const SyntheticEmbryoOptions& options) {
  for (int a = 0; a < 3; ++a) {
    if (options.size[a] < 1 || options.size[a] > kMaxSize) {
      return InvalidArgumentError("synthetic embryo: size along " + std::string(1, "xyz"[a]) +
                                  " is " + std::to_string(options.size[a]) + ", must be 1.." +
                                  std::to_string(kMaxSize));
    }
    if (!(std::isfinite(options.spacing_um[a]) && options.spacing_um[a] > 0)) {
      return InvalidArgumentError("synthetic embryo: spacing along " + std::string(1, "xyz"[a]) +
                                  " must be a positive number");
    }
  }
  if (options.channels < 1 || options.channels > kMaxChannels) {
    return InvalidArgumentError("synthetic embryo: " + std::to_string(options.channels) +
                                " channels, must be 1.." + std::to_string(kMaxChannels));
  }
  if (options.embryo_percent < 1 || options.embryo_percent > 100) {
    return InvalidArgumentError("synthetic embryo: embryo_percent " +
                                std::to_string(options.embryo_percent) + " is outside 1..100");
  }
  std::unique_ptr<SyntheticEmbryo> embryo(new SyntheticEmbryo());
  embryo->Build(options);
  OCTO_RETURN_IF_ERROR(embryo->info_.Validate());
  return embryo;
}

void SyntheticEmbryo::Build(const SyntheticEmbryoOptions& options) {
  seed_ = options.seed;
  size_ = options.size;
  info_.format = "synthetic";
  info_.size = options.size;
  info_.dtype = volume::DataType::kUint16;
  for (int a = 0; a < 3; ++a) info_.spacing_um[a] = options.spacing_um[a];
  for (int c = 0; c < options.channels; ++c) {
    info_.channels.push_back(volume::ChannelInfo{kChannelNames[c], kChannelColors[c]});
  }

  // The embryo: an ellipsoid spanning embryo_percent of the box along each axis.
  int64_t min_semi = 0;
  for (int a = 0; a < 3; ++a) {
    centre_[a] = size_[a] * kSub / 2;
    semi_axis_[a] = std::max<int64_t>(kSub / 2, size_[a] * kSub * options.embryo_percent / 200);
    // A one-voxel axis never moves a voxel off the centre plane, so it does not bound distances.
    if (size_[a] > 1) min_semi = min_semi ? std::min(min_semi, semi_axis_[a]) : semi_axis_[a];
    unit_coord_[a].resize(size_[a]);
    for (int64_t p = 0; p < size_[a]; ++p) {
      unit_coord_[a][p] = (Pos(p) - centre_[a]) * kUnit / semi_axis_[a];
    }
  }
  if (min_semi == 0) min_semi = kSub / 2;
  atten_x_.resize(size_[0]);
  for (int64_t x = 0; x < size_[0]; ++x) atten_x_[x] = static_cast<int32_t>(180 * x / size_[0]);

  const int64_t largest = std::max({size_[0], size_[1], size_[2]});
  const int64_t edge = std::max(kMinEdge, largest * kSub * kEdgeFraction / 100000);
  membrane_half_width_ = std::max<int64_t>(12, edge / 16);
  surface_half_width_ = membrane_half_width_ * 3 / 2;
  // Voxels whose normalised radius lies in this band may be within the ramp or the surface
  // membrane: |distance to surface| >= min_semi * |rho - 1| bounds it.
  const int64_t reach = std::max(kEdgeRamp, surface_half_width_) + kSub;
  const int64_t band = reach * kUnit / min_semi + 1;
  inner_r2_ = band >= kUnit ? -1 : (kUnit - band) * (kUnit - band);
  outer_r2_ = (kUnit + band) * (kUnit + band);

  auto unit_r2 = [&](const std::array<int64_t, 3>& p) {
    int64_t r2 = 0;
    for (int a = 0; a < 3; ++a) {
      int64_t u = (p[a] - centre_[a]) * kUnit / semi_axis_[a];
      r2 += u * u;
    }
    return r2;
  };

  // Nuclei: one per grid cell, jittered. Every cell's centre seeds the membrane pattern (so the
  // nearest seed of a voxel is almost always in the 3x3x3 cells around it); only those at least a
  // radius inside the embryo carry a visible nucleus.
  nucleus_grid_ = std::make_unique<Grid>(size_, edge);
  Grid& ng = *nucleus_grid_;
  const int64_t base_radius = edge * 42 / 100;
  for (int64_t k = 0; k < ng.cells[2]; ++k) {
    for (int64_t j = 0; j < ng.cells[1]; ++j) {
      for (int64_t i = 0; i < ng.cells[0]; ++i) {
        const uint64_t h = Hash(seed_, kTagNucleus, i, j, k);
        Nucleus n{};
        const int64_t cell[3] = {i, j, k};
        for (int a = 0; a < 3; ++a) {
          int64_t lo = ng.Lo(a, cell[a]), hi = ng.Lo(a, cell[a] + 1);
          n.centre[a] = lo + (hi - lo) * Pick(h, 10 * a, 120, 880) / 1000;
        }
        ng.At(i, j, k) = static_cast<int32_t>(nuclei_.size());
        nuclei_.push_back(n);
      }
    }
  }
  cell_of_x_.resize(size_[0]);
  for (int64_t x = 0; x < size_[0]; ++x) cell_of_x_[x] = static_cast<int32_t>(ng.CellOf(0, Pos(x)));
  for (int64_t k = 0; k < ng.cells[2]; ++k) {
    for (int64_t j = 0; j < ng.cells[1]; ++j) {
      for (int64_t i = 0; i < ng.cells[0]; ++i) {
        Nucleus& n = nuclei_[ng.At(i, j, k)];
        // A nucleus fills at most 46% of the way to its nearest neighbour, so none overlap.
        int64_t nearest2 = INT64_MAX;
        for (int64_t kk = std::max<int64_t>(0, k - 1); kk <= std::min(ng.cells[2] - 1, k + 1);
             ++kk) {
          for (int64_t jj = std::max<int64_t>(0, j - 1); jj <= std::min(ng.cells[1] - 1, j + 1);
               ++jj) {
            for (int64_t ii = std::max<int64_t>(0, i - 1); ii <= std::min(ng.cells[0] - 1, i + 1);
                 ++ii) {
              if (ii == i && jj == j && kk == k) continue;
              const Nucleus& m = nuclei_[ng.At(ii, jj, kk)];
              int64_t d2 = 0;
              for (int a = 0; a < 3; ++a)
                d2 += (m.centre[a] - n.centre[a]) * (m.centre[a] - n.centre[a]);
              nearest2 = std::min(nearest2, d2);
            }
          }
        }
        int64_t radius = base_radius;
        if (nearest2 != INT64_MAX) {
          radius = std::min(
              radius, static_cast<int64_t>(IntSqrt(static_cast<uint64_t>(nearest2))) * 46 / 100);
        }
        const uint64_t h = Hash(seed_, kTagNucleus, i, j, k);
        const uint64_t h2 = Mix(h);
        // About 4% are mitotic: condensed, brighter and elongated along one axis.
        const bool mitotic = (h2 & 1023) < 41;
        const int long_axis = static_cast<int>((h2 >> 10) % 3);
        for (int a = 0; a < 3; ++a) {
          int64_t r = Pick(h, 30 + 10 * a, radius * 88, radius * 110) / 100;
          if (mitotic) r = r * (a == long_axis ? 80 : 55) / 100;
          n.radius[a] = std::max<int64_t>(kSub / 2, r);
          n.inv_radius[a] = (int64_t{1} << 24) / n.radius[a];
        }
        const int64_t r2 = unit_r2(n.centre);
        if (r2 >= kUnit * kUnit) continue;
        int64_t depth = 0;  // Distance from the centre to the embryo surface (sub-units).
        {
          const int64_t rho = static_cast<int64_t>(IntSqrt(static_cast<uint64_t>(r2)));
          int64_t len2 = 0;
          for (int a = 0; a < 3; ++a)
            len2 += (n.centre[a] - centre_[a]) * (n.centre[a] - centre_[a]);
          const int64_t len = static_cast<int64_t>(IntSqrt(static_cast<uint64_t>(len2)));
          depth = rho == 0 ? INT64_MAX : len * (kUnit - rho) / rho;
        }
        if (depth < radius) continue;
        ++present_nuclei_;
        n.brightness =
            static_cast<int32_t>(mitotic ? Pick(h2, 20, 3200, 4200) : Pick(h2, 20, 1000, 2400));
        // The reporter marks most nuclei in the -x third of the embryo and a few elsewhere.
        const uint64_t hr = Hash(seed_, kTagReporter, i, j, k);
        const bool region = (n.centre[0] - centre_[0]) * 3 < -semi_axis_[0];
        const bool on = (hr & 1023) < (region ? 870u : 40u);
        if (on) n.reporter_brightness = static_cast<int32_t>(Pick(hr, 10, 700, 2200));
      }
    }
  }

  // Spots: a finer grid, a quarter of whose cells inside the embryo hold one spot.
  const int64_t spot_radius = std::max<int64_t>(24, edge * 12 / 100);
  spot_grid_ = std::make_unique<Grid>(size_, std::max(edge / 2, 4 * spot_radius));
  Grid& sg = *spot_grid_;
  for (int64_t k = 0; k < sg.cells[2]; ++k) {
    for (int64_t j = 0; j < sg.cells[1]; ++j) {
      for (int64_t i = 0; i < sg.cells[0]; ++i) {
        const uint64_t h = Hash(seed_, kTagSpot, i, j, k);
        if ((h >> 54) >= 256) continue;  // Keep 256 of 1024.
        Spot s;
        const int64_t cell[3] = {i, j, k};
        for (int a = 0; a < 3; ++a) {
          int64_t lo = sg.Lo(a, cell[a]), hi = sg.Lo(a, cell[a] + 1);
          // Anywhere in the cell (so no plane is free of spots); a spot's radius is at most a
          // quarter cell, so it never reaches past the neighbouring cells.
          s.centre[a] = lo + (hi - lo) * Pick(h, 10 * a, 0, 1000) / 1000;
        }
        if (unit_r2(s.centre) >= (kUnit * 95 / 100) * (kUnit * 95 / 100)) continue;
        s.radius = Pick(h, 30, spot_radius * 80, spot_radius * 120) / 100;
        s.brightness = static_cast<int32_t>(Pick(Mix(h), 0, 5000, 12000));
        sg.At(i, j, k) = static_cast<int32_t>(spots_.size());
        spots_.push_back(s);
      }
    }
  }

  // Nucleus profile by q >> 10, where q = (distance / radius)^2 * 2^20.
  nucleus_profile_.resize(kProfileCut / 1024 + 1);
  for (size_t i = 0; i < nucleus_profile_.size(); ++i) {
    int64_t rho = static_cast<int64_t>(IntSqrt(i * 1024));  // Radius fraction * 1024.
    int64_t t =
        std::clamp<int64_t>((kProfileEnd - rho) * 1024 / (kProfileEnd - kProfileFlat), 0, 1024);
    nucleus_profile_[i] = static_cast<int32_t>(Smoothstep1024(t));
  }
  // Camera noise: read noise sigma 3 plus shot noise (variance = signal / 2).
  noise_sigma_.resize(4096);
  for (int64_t i = 0; i < 4096; ++i) {
    int64_t level = i * 16 + 8;
    noise_sigma_[i] = static_cast<int32_t>(IntSqrt(static_cast<uint64_t>((9 + level / 2) * 256)));
  }
}

Status SyntheticEmbryo::ReadSlab(int channel, int64_t z0, int64_t nz, std::span<std::byte> out) {
  OCTO_RETURN_IF_ERROR(CheckSlabRequest(info_, channel, z0, nz, out.size()));
  RowScratch scratch;
  std::vector<uint16_t> row(size_[0]);
  const size_t row_bytes = row.size() * sizeof(uint16_t);
  std::byte* dst = out.data();
  for (int64_t z = z0; z < z0 + nz; ++z) {
    for (int64_t y = 0; y < size_[1]; ++y) {
      RenderRow(channel, y, z, scratch, row.data());
      std::memcpy(dst, row.data(), row_bytes);
      dst += row_bytes;
    }
  }
  return Status::Ok();
}

int64_t SyntheticEmbryo::SurfaceDistance(int64_t x, int64_t y, int64_t z, int64_t r2) const {
  const int64_t rho = static_cast<int64_t>(IntSqrt(static_cast<uint64_t>(r2)));
  if (rho == 0) return -semi_axis_[0];
  const int64_t d[3] = {Pos(x) - centre_[0], Pos(y) - centre_[1], Pos(z) - centre_[2]};
  const int64_t len =
      static_cast<int64_t>(IntSqrt(static_cast<uint64_t>(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])));
  // Distance along the ray from the centre: |p| * (rho - 1) / rho.
  return len * (rho - kUnit) / rho;
}

void SyntheticEmbryo::RenderRow(int channel, int64_t y, int64_t z, RowScratch& scratch,
                                uint16_t* out) const {
  const int64_t sx = size_[0];
  scratch.signal.assign(sx, 0);
  switch (channel) {
    case 0:
      SplatNuclei(y, z, false, scratch);
      break;
    case 1:
      RenderMembranes(y, z, scratch);
      break;
    case 2:
      SplatSpots(y, z, scratch);
      break;
    default:
      SplatNuclei(y, z, true, scratch);
      break;
  }
  const int32_t* signal = scratch.signal.data();
  const int64_t r2_yz =
      unit_coord_[1][y] * unit_coord_[1][y] + unit_coord_[2][z] * unit_coord_[2][z];
  const int64_t* ux = unit_coord_[0].data();
  const int64_t background = kBackground[channel];
  const int64_t autofluorescence = kAutofluorescence[channel];
  const uint64_t row_key = Hash(seed_, kTagNoise + channel, y, z);
  // Light-sheet attenuation: the sheet enters from -x, the detection objective looks from -z.
  const int64_t atten_z = 1024 - 260 * z / size_[2];
  for (int64_t x = 0; x < sx; ++x) {
    const int64_t r2 = ux[x] * ux[x] + r2_yz;
    int64_t inside = 0;  // 0..1024: how far inside the embryo (soft edge).
    int64_t surface = 0;
    if (r2 <= inner_r2_) {
      inside = 1024;
    } else if (r2 < outer_r2_) {
      const int64_t dist = SurfaceDistance(x, y, z, r2);
      inside = std::clamp<int64_t>(-dist * (1024 / kEdgeRamp), 0, 1024);
      if (channel == 1 && dist < surface_half_width_ && dist > -surface_half_width_) {
        const int64_t s = dist * dist * 1024 / (surface_half_width_ * surface_half_width_);
        surface = kSurfaceBrightness * (1024 - s) * (1024 - s) / (1024 * 1024);
      }
    }
    // Structures end at the embryo's surface; the surface itself is membrane.
    const int64_t sig = std::max(signal[x] * inside / 1024, surface);
    const int64_t atten = atten_z - atten_x_[x];
    const int64_t level =
        std::min<int64_t>(sig * atten / 1024 + autofluorescence * inside / 1024, 65535);
    const int64_t noise = Gaussian(Mix(row_key + static_cast<uint64_t>(x))) *
                          noise_sigma_[level >> 4] / (kGaussSigma * 16);
    out[x] = static_cast<uint16_t>(std::clamp<int64_t>(background + level + noise, 0, 65535));
  }
}

void SyntheticEmbryo::SplatNuclei(int64_t y, int64_t z, bool reporter_only,
                                  RowScratch& scratch) const {
  const Grid& g = *nucleus_grid_;
  const int64_t py = Pos(y), pz = Pos(z);
  const int64_t cj = g.CellOf(1, py), ck = g.CellOf(2, pz);
  int32_t* signal = scratch.signal.data();
  for (int64_t k = std::max<int64_t>(0, ck - 1); k <= std::min(g.cells[2] - 1, ck + 1); ++k) {
    for (int64_t j = std::max<int64_t>(0, cj - 1); j <= std::min(g.cells[1] - 1, cj + 1); ++j) {
      for (int64_t i = 0; i < g.cells[0]; ++i) {
        const int32_t index = g.At(i, j, k);
        if (index < 0) continue;
        const Nucleus& n = nuclei_[index];
        const int64_t peak = reporter_only ? n.reporter_brightness : n.brightness;
        if (peak == 0) continue;
        // t = distance / radius * 1024 per axis; q = |t|^2.
        const int64_t ty = ((py - n.centre[1]) * n.inv_radius[1]) >> 14;
        const int64_t tz = ((pz - n.centre[2]) * n.inv_radius[2]) >> 14;
        if (ty >= kProfileEnd || ty <= -kProfileEnd || tz >= kProfileEnd || tz <= -kProfileEnd) {
          continue;
        }
        const int64_t q_yz = ty * ty + tz * tz;
        if (q_yz >= kProfileCut) continue;
        const int64_t half =
            n.radius[0] * static_cast<int64_t>(IntSqrt(kProfileCut - q_yz)) / 1024 + kSub;
        const int64_t x0 = std::max<int64_t>(0, FloorDiv(n.centre[0] - half, kSub));
        const int64_t x1 = std::min<int64_t>(size_[0] - 1, FloorDiv(n.centre[0] + half, kSub));
        for (int64_t x = x0; x <= x1; ++x) {
          const int64_t tx = ((Pos(x) - n.centre[0]) * n.inv_radius[0]) >> 14;
          const int64_t q = tx * tx + q_yz;
          if (q >= kProfileCut) continue;
          const int32_t v = static_cast<int32_t>(peak * nucleus_profile_[q >> 10] >> 10);
          signal[x] = std::max(signal[x], v);
        }
      }
    }
  }
}

void SyntheticEmbryo::SplatSpots(int64_t y, int64_t z, RowScratch& scratch) const {
  const Grid& g = *spot_grid_;
  const int64_t py = Pos(y), pz = Pos(z);
  const int64_t cj = g.CellOf(1, py), ck = g.CellOf(2, pz);
  int32_t* signal = scratch.signal.data();
  for (int64_t k = std::max<int64_t>(0, ck - 1); k <= std::min(g.cells[2] - 1, ck + 1); ++k) {
    for (int64_t j = std::max<int64_t>(0, cj - 1); j <= std::min(g.cells[1] - 1, cj + 1); ++j) {
      for (int64_t i = 0; i < g.cells[0]; ++i) {
        const int32_t index = g.At(i, j, k);
        if (index < 0) continue;
        const Spot& s = spots_[index];
        const int64_t dy = py - s.centre[1], dz = pz - s.centre[2];
        const int64_t r2 = s.radius * s.radius;
        const int64_t d2_yz = dy * dy + dz * dz;
        if (d2_yz >= r2) continue;
        const int64_t half = static_cast<int64_t>(IntSqrt(r2 - d2_yz)) + 1;
        const int64_t x0 = std::max<int64_t>(0, FloorDiv(s.centre[0] - half, kSub));
        const int64_t x1 = std::min<int64_t>(size_[0] - 1, FloorDiv(s.centre[0] + half, kSub));
        for (int64_t x = x0; x <= x1; ++x) {
          const int64_t dx = Pos(x) - s.centre[0];
          const int64_t d2 = dx * dx + d2_yz;
          if (d2 >= r2) continue;
          // A smooth bump: (1 - d^2/r^2)^2.
          const int64_t t = 1024 - d2 * 1024 / r2;
          const int32_t v = static_cast<int32_t>(s.brightness * t * t / (1024 * 1024));
          signal[x] = std::max(signal[x], v);
        }
      }
    }
  }
}

void SyntheticEmbryo::RenderMembranes(int64_t y, int64_t z, RowScratch& scratch) const {
  const Grid& g = *nucleus_grid_;
  const int64_t py = Pos(y), pz = Pos(z);
  const int64_t cj = g.CellOf(1, py), ck = g.CellOf(2, pz);
  // Candidates: nuclei of the 3x3 cells around this row in (y, z), for every x cell; their
  // (dy^2 + dz^2) is constant along the row.
  scratch.cand_x.clear();
  scratch.cand_pre.clear();
  scratch.cand_index.clear();
  scratch.cell_start.assign(g.cells[0] + 1, 0);
  for (int64_t i = 0; i < g.cells[0]; ++i) {
    scratch.cell_start[i] = static_cast<int64_t>(scratch.cand_x.size());
    for (int64_t k = std::max<int64_t>(0, ck - 1); k <= std::min(g.cells[2] - 1, ck + 1); ++k) {
      for (int64_t j = std::max<int64_t>(0, cj - 1); j <= std::min(g.cells[1] - 1, cj + 1); ++j) {
        const int32_t index = g.At(i, j, k);
        if (index < 0) continue;
        const Nucleus& n = nuclei_[index];
        const int64_t dy = py - n.centre[1], dz = pz - n.centre[2];
        scratch.cand_x.push_back(n.centre[0]);
        scratch.cand_pre.push_back(dy * dy + dz * dz);
        scratch.cand_index.push_back(index);
      }
    }
  }
  scratch.cell_start[g.cells[0]] = static_cast<int64_t>(scratch.cand_x.size());
  // Per x cell, the candidates of it and its two x neighbours sorted by (dy^2 + dz^2), so the
  // nearest-two search below can stop as soon as that alone exceeds the second best distance.
  scratch.merged_x.clear();
  scratch.merged_pre.clear();
  scratch.merged_index.clear();
  scratch.merged_start.assign(g.cells[0] + 1, 0);
  for (int64_t i = 0; i < g.cells[0]; ++i) {
    scratch.merged_start[i] = static_cast<int64_t>(scratch.merged_x.size());
    const int64_t begin = scratch.cell_start[std::max<int64_t>(0, i - 1)];
    const int64_t end = scratch.cell_start[std::min(g.cells[0], i + 2)];
    scratch.order.clear();
    for (int64_t c = begin; c < end; ++c) scratch.order.push_back(c);
    std::sort(scratch.order.begin(), scratch.order.end(), [&](int64_t l, int64_t r) {
      return std::pair(scratch.cand_pre[l], l) < std::pair(scratch.cand_pre[r], r);
    });
    for (int64_t c : scratch.order) {
      scratch.merged_x.push_back(scratch.cand_x[c]);
      scratch.merged_pre.push_back(scratch.cand_pre[c]);
      scratch.merged_index.push_back(scratch.cand_index[c]);
    }
  }
  scratch.merged_start[g.cells[0]] = static_cast<int64_t>(scratch.merged_x.size());

  const int64_t* cx = scratch.merged_x.data();
  const int64_t* pre = scratch.merged_pre.data();
  int32_t* signal = scratch.signal.data();
  const int64_t r2_yz =
      unit_coord_[1][y] * unit_coord_[1][y] + unit_coord_[2][z] * unit_coord_[2][z];
  const int64_t* ux = unit_coord_[0].data();
  const int64_t w2 = membrane_half_width_ * membrane_half_width_;
  int32_t pair_a = -1, pair_b = -1;
  int64_t pair_length = 0, pair_brightness = 0, pair_limit = 0;
  for (int64_t x = 0; x < size_[0]; ++x) {
    if (ux[x] * ux[x] + r2_yz >= kUnit * kUnit) continue;  // Membranes only inside the embryo.
    const int64_t px = Pos(x);
    const int64_t ci = cell_of_x_[x];
    const int64_t begin = scratch.merged_start[ci];
    const int64_t end = scratch.merged_start[ci + 1];
    // The two nearest nucleus centres.
    int64_t d1 = INT64_MAX, d2 = INT64_MAX, b1 = -1, b2 = -1;
    for (int64_t c = begin; c < end; ++c) {
      if (pre[c] >= d2) break;  // Sorted: no later candidate can be nearer.
      const int64_t dx = px - cx[c];
      const int64_t d = dx * dx + pre[c];
      if (d < d2) {
        if (d < d1) {
          d2 = d1, b2 = b1;
          d1 = d, b1 = c;
        } else {
          d2 = d, b2 = c;
        }
      }
    }
    if (b2 < 0) continue;
    int32_t a = scratch.merged_index[b1], b = scratch.merged_index[b2];
    if (a > b) std::swap(a, b);
    if (a != pair_a || b != pair_b) {
      const Nucleus& na = nuclei_[a];
      const Nucleus& nb = nuclei_[b];
      int64_t l2 = 0;
      for (int ax = 0; ax < 3; ++ax) {
        const int64_t d = na.centre[ax] - nb.centre[ax];
        l2 += d * d;
      }
      pair_a = a, pair_b = b;
      pair_length = static_cast<int64_t>(IntSqrt(static_cast<uint64_t>(l2)));
      // The detection PSF is long along z: a membrane seen edge-on (normal in the xy plane)
      // collects more light per voxel than one lying in the image plane.
      const int64_t nz = na.centre[2] - nb.centre[2];
      const int64_t nz2 = l2 > 0 ? nz * nz * 1024 / l2 : 0;
      pair_brightness = kMembraneBrightness * (1024 - 850 * nz2 / 1024) / 1024;
      pair_limit = 2 * pair_length * membrane_half_width_;
    }
    // Distance to the bisector plane of the two centres: (d2^2 - d1^2) / (2 |c1 - c2|); the
    // comparison first avoids a division for the many voxels far from any membrane.
    if (d2 - d1 >= pair_limit) continue;
    const int64_t w = (d2 - d1) / (2 * pair_length);
    const int64_t t = 1024 - w * w * 1024 / w2;
    signal[x] = static_cast<int32_t>(pair_brightness * t * t / (1024 * 1024));
  }
}

}  // namespace octoscope::io
