#include "octree/slab_ingest.h"

#include <algorithm>
#include <cstring>
#include <string>
#include <utility>

namespace octoscope::octree {

Result<std::unique_ptr<SlabIngest>> SlabIngest::Create(Octree* tree, const IngestOptions& options) {
  if (tree == nullptr) return InvalidArgumentError("slab ingest: no octree");
  const uint64_t planes = static_cast<uint64_t>(tree->geometry().volume_size()[2]) *
                          static_cast<uint64_t>(tree->geometry().channels());
  if (!options.inserted.empty() && options.inserted.size() != planes) {
    return InvalidArgumentError("slab ingest: " + std::to_string(options.inserted.size()) +
                                " inserted-plane flags for " + std::to_string(planes) + " planes");
  }
  return std::unique_ptr<SlabIngest>(new SlabIngest(tree, options));
}

SlabIngest::SlabIngest(Octree* tree, const IngestOptions& options)
    : tree_(tree),
      options_(options),
      channels_(tree->geometry().channels()),
      depth_(tree->geometry().brick_size()[2]),
      plane_bytes_(static_cast<uint64_t>(tree->geometry().volume_size()[0]) *
                   static_cast<uint64_t>(tree->geometry().volume_size()[1]) *
                   static_cast<uint64_t>(tree->geometry().bytes_per_sample())),
      planes_(tree->geometry().volume_size()[2]) {
  layer_done_.assign(static_cast<size_t>((planes_ + depth_ - 1) / depth_), 0);
  progress_.planes_total = static_cast<uint64_t>(planes_) * static_cast<uint64_t>(channels_);
  if (options_.inserted.empty()) return;
  const uint64_t present = static_cast<uint64_t>(std::count_if(
      options_.inserted.begin(), options_.inserted.end(), [](uint8_t f) { return f; }));
  progress_.planes_received = present;
  progress_.planes_inserted = present;
  for (size_t index = 0; index < layer_done_.size(); ++index) {
    const int64_t z0 = static_cast<int64_t>(index) * depth_, z1 = std::min(planes_, z0 + depth_);
    bool all = true;
    for (int c = 0; c < channels_ && all; ++c) {
      for (int64_t z = z0; z < z1 && all; ++z) all = WasInserted(c, z);
    }
    if (all) {
      layer_done_[index] = 1;
      ++progress_.layers_inserted;
    }
  }
}

bool SlabIngest::WasInserted(int channel, int64_t z) const {
  return !options_.inserted.empty() &&
         options_.inserted[static_cast<size_t>(channel * planes_ + z)] != 0;
}

SlabIngest::~SlabIngest() = default;

Result<SlabIngest::Layer*> SlabIngest::LayerLocked(int64_t index,
                                                   std::unique_lock<std::mutex>& lock) {
  (void)lock;
  if (auto it = layers_.find(index); it != layers_.end()) return it->second.get();
  auto layer = std::make_unique<Layer>();
  layer->z0 = index * depth_;
  layer->nz = std::min(depth_, planes_ - layer->z0);
  const uint64_t bytes = static_cast<uint64_t>(channels_) * layer->nz * plane_bytes_;
  const uint64_t full_bytes = static_cast<uint64_t>(channels_) * depth_ * plane_bytes_;
  if (bytes == full_bytes && !spare_.empty()) {
    layer->ram = std::move(spare_.back());  // Already counted in staged_bytes_.
    spare_.pop_back();
    layer->ram_bytes = bytes;
  } else if (staged_bytes_ + bytes <= options_.staging_bytes) {
    // Not zero-filled: every byte is written by Stage before it is read.
    layer->ram.reset(new (std::nothrow) std::byte[bytes]);
    if (!layer->ram) return ResourceExhaustedError("slab ingest: out of memory staging a layer");
    layer->ram_bytes = bytes;
    staged_bytes_ += bytes;
  } else if (!options_.scratch_dir.empty()) {
    OCTO_ASSIGN_OR_RETURN(layer->file, ScratchFile::Create(options_.scratch_dir));
    ++progress_.scratch_layers;
  } else {
    return ResourceExhaustedError("slab ingest: a brick layer of " + std::to_string(bytes >> 20) +
                                  " MiB does not fit the staging budget of " +
                                  std::to_string(options_.staging_bytes >> 20) +
                                  " MiB and no scratch directory was given");
  }
  layer->state.assign(static_cast<size_t>(channels_ * layer->nz), PlaneState::kEmpty);
  layer->counted.assign(layer->state.size(), 0);
  layer->waiting = channels_ * layer->nz;
  // Planes of a resumed build that the octree holds already: the layer waits for the others.
  for (int c = 0; c < channels_; ++c) {
    for (int64_t p = 0; p < layer->nz; ++p) {
      if (!WasInserted(c, layer->z0 + p)) continue;
      const size_t i = static_cast<size_t>(c * layer->nz + p);
      layer->state[i] = PlaneState::kInserted;
      layer->counted[i] = 3;
      --layer->waiting;
    }
  }
  Layer* raw = layer.get();
  layers_.emplace(index, std::move(layer));
  return raw;
}

Status SlabIngest::Stage(Layer& layer, int channel, int64_t first, int64_t count,
                         const std::byte* data) {
  const uint64_t offset = (static_cast<uint64_t>(channel) * layer.nz + first) * plane_bytes_;
  const uint64_t bytes = static_cast<uint64_t>(count) * plane_bytes_;
  if (layer.ram) {
    std::memcpy(layer.ram.get() + offset, data, bytes);
    return Status::Ok();
  }
  return layer.file->WriteAt(offset, std::span<const std::byte>(data, bytes));
}

Status SlabIngest::Add(int channel, int64_t z0, int64_t nz, std::span<const std::byte> data) {
  if (channel < 0 || channel >= channels_) {
    return InvalidArgumentError("slab ingest: channel " + std::to_string(channel) + " of " +
                                std::to_string(channels_));
  }
  if (nz <= 0 || z0 < 0 || z0 > planes_ - nz) {
    return OutOfRangeError("slab ingest: planes [" + std::to_string(z0) + ", " +
                           std::to_string(z0 + nz) + ") outside [0, " + std::to_string(planes_) +
                           ")");
  }
  if (data.size() != static_cast<uint64_t>(nz) * plane_bytes_) {
    return InvalidArgumentError("slab ingest: " + std::to_string(nz) + " planes need " +
                                std::to_string(static_cast<uint64_t>(nz) * plane_bytes_) +
                                " bytes, got " + std::to_string(data.size()));
  }
  std::unique_lock lock(mu_);
  for (int64_t z = z0; z < z0 + nz;) {
    const int64_t index = z / depth_;
    const int64_t end = std::min(z0 + nz, (index + 1) * depth_);
    const std::byte* part = data.data() + static_cast<uint64_t>(z - z0) * plane_bytes_;
    Layer* layer = nullptr;
    // Wait until no other thread writes or inserts these planes.
    for (;;) {
      if (layer_done_[index]) break;
      OCTO_ASSIGN_OR_RETURN(layer, LayerLocked(index, lock));
      bool free = true;
      for (int64_t p = z; p < end && free; ++p) {
        const PlaneState s = layer->state[channel * layer->nz + (p - layer->z0)];
        free = s != PlaneState::kWriting && s != PlaneState::kInserting;
      }
      if (free) break;
      cv_.wait(lock);
    }
    if (layer_done_[index]) {
      // The layer was inserted already: this is a plane arriving again.
      lock.unlock();
      OCTO_RETURN_IF_ERROR(InsertDirect(
          channel, z, end - z,
          std::span<const std::byte>(part, static_cast<uint64_t>(end - z) * plane_bytes_)));
      lock.lock();
      z = end;
      continue;
    }
    const int64_t first = z - layer->z0, count = end - z;
    for (int64_t p = first; p < first + count; ++p) {
      PlaneState& s = layer->state[channel * layer->nz + p];
      if (s != PlaneState::kEmpty) ++layer->waiting;  // A replaced plane: received again below.
      s = PlaneState::kWriting;
    }
    lock.unlock();
    Status staged = Stage(*layer, channel, first, count, part);
    lock.lock();
    for (int64_t p = first; p < first + count; ++p) {
      const size_t i = static_cast<size_t>(channel * layer->nz + p);
      layer->state[i] = staged.ok() ? PlaneState::kReceived : PlaneState::kEmpty;
      if (!staged.ok()) continue;
      --layer->waiting;
      if ((layer->counted[i] & 1) == 0) {
        layer->counted[i] |= 1;
        ++progress_.planes_received;
      }
    }
    cv_.notify_all();
    OCTO_RETURN_IF_ERROR(staged);
    if (layer->waiting == 0 && !layer->busy) OCTO_RETURN_IF_ERROR(InsertPending(index, lock));
    z = end;
  }
  return Status::Ok();
}

Status SlabIngest::InsertPending(int64_t index, std::unique_lock<std::mutex>& lock) {
  Layer* layer = layers_.at(index).get();
  layer->busy = true;
  Status status;
  for (;;) {
    bool any = false;
    for (PlaneState& s : layer->state) {
      if (s == PlaneState::kReceived) {
        s = PlaneState::kInserting;
        any = true;
      }
    }
    if (!any) break;
    lock.unlock();
    status = InsertMarked(*layer);
    lock.lock();
    for (size_t i = 0; i < layer->state.size(); ++i) {
      PlaneState& s = layer->state[i];
      if (s != PlaneState::kInserting) continue;
      s = status.ok() ? PlaneState::kInserted : PlaneState::kReceived;
      if (status.ok() && (layer->counted[i] & 2) == 0) {
        layer->counted[i] |= 2;
        ++progress_.planes_inserted;
      }
    }
    cv_.notify_all();
    // Planes that arrived meanwhile are inserted now only when they complete the layer (a Flush
    // takes the others).
    if (!status.ok() || layer->waiting != 0) break;
  }
  layer->busy = false;
  cv_.notify_all();
  const bool done = status.ok() && layer->waiting == 0 &&
                    std::all_of(layer->state.begin(), layer->state.end(),
                                [](PlaneState s) { return s == PlaneState::kInserted; });
  if (done) {
    if (layer->ram && layer->nz == depth_) {
      spare_.push_back(std::move(layer->ram));  // Stays counted: reused by the next layer.
    } else {
      staged_bytes_ -= layer->ram_bytes;
    }
    layers_.erase(index);
    layer_done_[index] = 1;
    ++progress_.layers_inserted;
  }
  return status;
}

Status SlabIngest::InsertMarked(Layer& layer) {
  const BrickGeometry& g = tree_->geometry();
  const int64_t sx = g.volume_size()[0], sy = g.volume_size()[1];
  const uint64_t row_bytes = static_cast<uint64_t>(sx) * g.bytes_per_sample();
  auto mask_of = [&](int64_t p) {
    uint64_t mask = 0;
    for (int c = 0; c < channels_; ++c) {
      if (layer.state[c * layer.nz + p] == PlaneState::kInserting) mask |= uint64_t{1} << c;
    }
    return mask;
  };
  std::vector<ChannelBlock> blocks;
  std::vector<std::vector<std::byte>> rows(channels_);
  for (int64_t a = 0; a < layer.nz;) {
    const uint64_t mask = mask_of(a);
    int64_t b = a + 1;
    while (b < layer.nz && mask_of(b) == mask) ++b;
    if (mask == 0) {
      a = b;
      continue;
    }
    // Planes [a, b) of the channels in `mask`: one insert (RAM), or one per brick row (scratch).
    const int64_t run = b - a;
    const int64_t row_step = layer.ram ? sy : g.brick_size()[1];
    for (int64_t y0 = 0; y0 < sy; y0 += row_step) {
      const int64_t ny = std::min(row_step, sy - y0);
      blocks.clear();
      for (int c = 0; c < channels_; ++c) {
        if (((mask >> c) & 1) == 0) continue;
        const uint64_t channel_offset = (static_cast<uint64_t>(c) * layer.nz + a) * plane_bytes_;
        if (layer.ram) {
          blocks.push_back({c, std::span<const std::byte>(layer.ram.get() + channel_offset,
                                                          run * plane_bytes_)});
          continue;
        }
        const uint64_t chunk = static_cast<uint64_t>(ny) * row_bytes;
        rows[c].resize(static_cast<size_t>(run * chunk));
        for (int64_t p = 0; p < run; ++p) {
          OCTO_RETURN_IF_ERROR(layer.file->ReadAt(
              channel_offset + p * plane_bytes_ + static_cast<uint64_t>(y0) * row_bytes,
              std::span<std::byte>(rows[c].data() + p * chunk, chunk)));
        }
        blocks.push_back({c, rows[c]});
      }
      const Box box{{0, y0, layer.z0 + a}, {sx, y0 + ny, layer.z0 + b}};
      OCTO_RETURN_IF_ERROR(tree_->Insert(box, blocks, options_.workers));
    }
    a = b;
  }
  return Status::Ok();
}

Status SlabIngest::InsertDirect(int channel, int64_t z0, int64_t nz,
                                std::span<const std::byte> data) {
  const BrickGeometry& g = tree_->geometry();
  const Box box{{0, 0, z0}, {g.volume_size()[0], g.volume_size()[1], z0 + nz}};
  const ChannelBlock block{channel, data};
  return tree_->Insert(box, std::span<const ChannelBlock>(&block, 1), options_.workers);
}

Status SlabIngest::Flush() {
  std::unique_lock lock(mu_);
  std::vector<int64_t> pending;
  for (const auto& [index, layer] : layers_) {
    if (layer->busy) continue;
    if (std::any_of(layer->state.begin(), layer->state.end(),
                    [](PlaneState s) { return s == PlaneState::kReceived; })) {
      pending.push_back(index);
    }
  }
  std::sort(pending.begin(), pending.end());
  for (int64_t index : pending) {
    auto it = layers_.find(index);
    if (it == layers_.end() || it->second->busy) continue;  // Taken meanwhile.
    OCTO_RETURN_IF_ERROR(InsertPending(index, lock));
  }
  return Status::Ok();
}

IngestProgress SlabIngest::progress() const {
  std::lock_guard lock(mu_);
  IngestProgress p = progress_;
  p.staged_bytes = staged_bytes_;
  return p;
}

bool SlabIngest::complete() const {
  std::lock_guard lock(mu_);
  return std::all_of(layer_done_.begin(), layer_done_.end(), [](uint8_t d) { return d != 0; });
}

uint64_t SlabIngest::pending_planes() const {
  std::lock_guard lock(mu_);
  uint64_t n = 0;
  for (const auto& [index, layer] : layers_) {
    n += static_cast<uint64_t>(
        std::count(layer->state.begin(), layer->state.end(), PlaneState::kReceived));
  }
  return n;
}

}  // namespace octoscope::octree
