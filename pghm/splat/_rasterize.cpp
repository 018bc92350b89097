// Native splatter of pghm.splat: forward and backward of spec steps 5-6 (see the docstring of
// pghm/splat/__init__.py), parallel over screen tiles with at::parallel_for.
// Readable twin: pghm/splat/_torch_impl.py; the tests hold the two to each other.
//
// Design (docs/splat.md has the measurements):
//  * Binning. Visible Gaussians arrive in global depth order; a counting sort by tile keeps that
//    order, so every tile's list is front to back, exactly the spec's per-pixel order.
//  * Forward, per tile, Gaussian-major. The tile keeps T, colour and depth per pixel. Each
//    Gaussian visits only its footprint: for each row of its box, the span of columns where
//    d^T Q d <= k (the roots of a quadratic), in blocks of kLanes pixels that compile to SIMD
//    vectors, with the exact alpha test per pixel.
//  * Backward, per tile, back to front over the (G, T_i) of every block the forward sweep
//    composited, with per-pixel "behind" accumulators (colour, depth, transmittance). A forward
//    pass asked to record them keeps the tiles' blocks (a Recording, up to a size it is given) for
//    its backward pass, which sweeps a tile not kept again to find them. Nothing is divided by
//    (1 - alpha): 3DGS's reconstruction T_i = T_{i+1} / (1 - alpha_i) breaks once T underflows in
//    heavy overlap, this does not.
//  * Each (tile, Gaussian) pair writes its gradient to its own slot and a serial pass sums the
//    slots per Gaussian: no atomics, bit-for-bit deterministic for any thread count.
//  * Scheduling: tiles sorted by list length, longest first, handed out by an atomic counter.
//
// Per-Gaussian inputs in float64 (means2d, conics) are turned into tile-local coordinates in
// double before rounding to the working type, so the per-pixel offsets d lose no precision.

#include <ATen/Parallel.h>
#include <ATen/core/Tensor.h>
#include <ATen/ops/empty.h>
#include <ATen/ops/zeros.h>
#include <torch/csrc/utils/pybind.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <memory>
#include <mutex>
#include <numeric>
#include <tuple>
#include <type_traits>
#include <utility>
#include <vector>

namespace {

// Columns of the per-Gaussian gradient returned by backward(); native.py reads the same layout.
enum GradColumn : int { kU, kV, kConicA, kConicB, kConicC, kOpacity, kRed, kGreen, kBlue, kDepth, kNumGrads };

struct Settings {
  int64_t batch, num_gaussians, width, height, tile_size, tiles_x, tiles_y;
  double alpha_cutoff, alpha_max, transmittance_stop;

  int64_t tiles_per_image() const { return tiles_x * tiles_y; }
  int64_t num_tiles() const { return batch * tiles_per_image(); }
};

template <typename scalar_t>
struct Inputs {
  const double* means2d;       // (B N, 2)
  const double* conics;        // (B N, 3)
  const scalar_t* colors;      // (B N, 3)
  const scalar_t* opacities;   // (B N)
  const scalar_t* depths;      // (B N)
  const int32_t* bbox;         // (B N, 4) inclusive x0, x1, y0, y1, clipped to the image
  const double* radius2;       // (B N) k: alpha >= cutoff where d^T Q d <= k (padded, as the box)
  const scalar_t* background;  // (3)
};

struct Tile {
  int64_t image, x0, y0, width, height;
};

Tile tile_at(int64_t index, const Settings& s) {
  const int64_t image = index / s.tiles_per_image();
  const int64_t within = index % s.tiles_per_image();
  const int64_t x0 = (within % s.tiles_x) * s.tile_size;
  const int64_t y0 = (within / s.tiles_x) * s.tile_size;
  return {image, x0, y0, std::min(s.tile_size, s.width - x0), std::min(s.tile_size, s.height - y0)};
}

// One Gaussian seen from one tile, in tile-local pixels: pixel (row r, column c) has its centre at
// (c + 1/2, r + 1/2), and q = a dx^2 + 2 b dx dy + c dy^2 with d = centre - (u, v).
template <typename scalar_t>
struct Splat {
  scalar_t u, v, a, b, c, opacity;
  // Row dy meets the ellipse q <= k in the columns u - b dy / a +- sqrt(a k - (a c - b^2) dy^2) / a.
  scalar_t inverse_a, a_k, determinant;
  int32_t row0, row1, col0, col1;  // the footprint box inside the tile, inclusive
};

template <typename scalar_t>
Splat<scalar_t> make_splat(const Inputs<scalar_t>& in, int64_t g, const Tile& tile, const Settings& s) {
  Splat<scalar_t> splat;
  splat.u = static_cast<scalar_t>(in.means2d[2 * g] - static_cast<double>(tile.x0));
  splat.v = static_cast<scalar_t>(in.means2d[2 * g + 1] - static_cast<double>(tile.y0));
  splat.a = static_cast<scalar_t>(in.conics[3 * g]);
  splat.b = static_cast<scalar_t>(in.conics[3 * g + 1]);
  splat.c = static_cast<scalar_t>(in.conics[3 * g + 2]);
  splat.opacity = in.opacities[g];
  const double a = in.conics[3 * g], b = in.conics[3 * g + 1], c = in.conics[3 * g + 2];
  splat.inverse_a = static_cast<scalar_t>(1.0 / a);
  splat.a_k = static_cast<scalar_t>(a * in.radius2[g]);
  splat.determinant = static_cast<scalar_t>(a * c - b * b);
  const int32_t* box = in.bbox + 4 * g;
  splat.col0 = static_cast<int32_t>(std::max<int64_t>(box[0] - tile.x0, 0));
  splat.col1 = static_cast<int32_t>(std::min<int64_t>(box[1] - tile.x0, tile.width - 1));
  splat.row0 = static_cast<int32_t>(std::max<int64_t>(box[2] - tile.y0, 0));
  splat.row1 = static_cast<int32_t>(std::min<int64_t>(box[3] - tile.y0, tile.height - 1));
  return splat;
}

// exp(x) for float within 1.02 ulp (checked on every float in [-87, 0]), branch-free so that
// loops calling it vectorise. Cephes expf: x = n ln 2 + r with |r| <= ln 2 / 2, a polynomial
// for e^r, 2^n from the exponent bits.
// Arguments below -87 return exp(-87) ~ 1.6e-38, far below any alpha cut-off.
inline float exp_fast(float x) {
  x = std::max(x, -87.0f);
  const float n = std::floor(x * 1.44269504088896341f + 0.5f);
  float r = x - n * 0.693359375f;  // ln 2 split in two so that n ln 2 is exact in float
  r -= n * -2.12194440e-4f;
  float p = 1.9875691500e-4f;
  p = p * r + 1.3981999507e-3f;
  p = p * r + 8.3334519073e-3f;
  p = p * r + 4.1665795894e-2f;
  p = p * r + 1.6666665459e-1f;
  p = p * r + 5.0000001201e-1f;
  p = p * r * r + r + 1.0f;
  const int32_t bits = (static_cast<int32_t>(n) + 127) << 23;
  float scale;
  std::memcpy(&scale, &bits, sizeof(scale));
  return p * scale;
}

inline double exp_fast(double x) { return std::exp(x); }  // float64 is the checking path, not the fast one

// Pixels are processed in blocks of kLanes consecutive columns of one row: every loop over a
// block's lanes has a fixed trip count and no branches, so it compiles to one SIMD vector.
// Lanes outside the footprint carry G = 0, which composites as alpha = 0: bit-for-bit a no-op.
constexpr int kLanes = 8;

// Calls visit(row, col) for the blocks [col, col + kLanes) covering, row by row, the columns
// where d^T Q d <= k (footprint box inside the tile); the block's G come from block_gauss().
template <typename scalar_t, typename Visit>
inline void for_each_block(const Splat<scalar_t>& splat, Visit&& visit) {
  const scalar_t half = static_cast<scalar_t>(0.5);
  for (int32_t row = splat.row0; row <= splat.row1; ++row) {
    const scalar_t dy = static_cast<scalar_t>(row) + half - splat.v;
    const scalar_t discriminant = splat.a_k - splat.determinant * dy * dy;
    if (!(discriminant >= 0)) {
      continue;
    }
    const scalar_t centre = splat.u - splat.b * dy * splat.inverse_a;
    const scalar_t half_width = std::sqrt(discriminant) * splat.inverse_a;
    // floor / ceil widen the span by up to a pixel; the alpha test decides.
    const scalar_t left = std::floor(centre - half_width - half);
    const scalar_t right = std::ceil(centre + half_width - half);
    const int32_t col0 = static_cast<int32_t>(std::max(static_cast<scalar_t>(splat.col0), left));
    const int32_t col1 = static_cast<int32_t>(std::min(static_cast<scalar_t>(splat.col1), right));
    for (int32_t col = col0; col <= col1; col += kLanes) {
      visit(row, col, col1);
    }
  }
}

// G = exp(-q / 2) of the block's pixels, 0 where the pixel is past `last` or its raw alpha
// opacity * G stays below the cut-off (the spec's ALPHA_MIN test).
template <typename scalar_t>
inline void block_gauss(const Splat<scalar_t>& splat, int32_t row, int32_t col, int32_t last, scalar_t cutoff,
                        scalar_t* gauss) {
  const scalar_t half = static_cast<scalar_t>(0.5);
  const scalar_t dy = static_cast<scalar_t>(row) + half - splat.v;
#pragma omp simd
  for (int lane = 0; lane < kLanes; ++lane) {
    const scalar_t dx = static_cast<scalar_t>(col + lane) + half - splat.u;
    const scalar_t q = splat.a * dx * dx + 2 * splat.b * dx * dy + splat.c * dy * dy;
    const scalar_t g = exp_fast(-half * q);
    const bool inside = (col + lane <= last) & (splat.opacity * g >= cutoff);  // `&`: no branch
    gauss[lane] = inside ? g : scalar_t(0);
  }
}

// One block remembered by a recording forward sweep, for the backward pass.
template <typename scalar_t>
struct Block {
  int32_t row, col;
  scalar_t gauss[kLanes];          // G, 0 for lanes that do not take part
  scalar_t transmittance[kLanes];  // T_i in front of this Gaussian
};

// The blocks of one tile's forward sweep, in compositing order, as its backward pass reads them.
template <typename scalar_t>
struct TileRecord {
  std::vector<Block<scalar_t>> blocks;
  std::vector<int64_t> first_block;  // per list entry, its first record in `blocks`; then the total
  bool kept = false;                 // false: not recorded (the recording's size reached its limit)
};

// The tiles' records of the recordings freed last, reused by the next forward passes that record:
// a fit's steps record about as many blocks each time (a render or two a step), and fresh memory
// for them (allocation and its page faults) cost more than the second sweep it saves. Up to
// kSpareBytes are kept, in at most kSpareSets sets.
constexpr int64_t kSpareBytes = int64_t{512} << 20;
constexpr size_t kSpareSets = 4;

template <typename scalar_t>
int64_t capacity_bytes(const std::vector<TileRecord<scalar_t>>& tiles) {
  int64_t total = 0;
  for (const TileRecord<scalar_t>& tile : tiles) {
    total += tile.blocks.capacity() * sizeof(Block<scalar_t>) + tile.first_block.capacity() * sizeof(int64_t);
  }
  return total;
}

template <typename scalar_t>
struct Spare {
  std::mutex mutex;
  std::vector<std::vector<TileRecord<scalar_t>>> sets;
  int64_t bytes = 0;

  // Never destroyed: a Recording that Python frees while the process exits still has it to give to.
  static Spare& instance() {
    static Spare* spare = new Spare;
    return *spare;
  }

  std::vector<TileRecord<scalar_t>> take() {
    std::lock_guard<std::mutex> lock(mutex);
    if (sets.empty()) {
      return {};
    }
    std::vector<TileRecord<scalar_t>> tiles = std::move(sets.back());
    sets.pop_back();
    bytes -= capacity_bytes(tiles);
    return tiles;
  }

  void give(std::vector<TileRecord<scalar_t>>&& freed) {
    if (freed.empty()) {
      return;
    }
    const int64_t size = capacity_bytes(freed);
    std::lock_guard<std::mutex> lock(mutex);
    if (sets.size() < kSpareSets && bytes + size <= kSpareBytes) {
      bytes += size;
      sets.push_back(std::move(freed));
    }
  }
};

// The tiles' records of one forward pass (forward() with a positive record_bytes), kept for its
// backward pass so that it does not sweep them again. One of the two vectors is used, as the
// colours' dtype; tiles are recorded while the blocks recorded take less than `limit` bytes.
struct Recording {
  std::vector<TileRecord<float>> single;
  std::vector<TileRecord<double>> twice;
  std::atomic<int64_t> recorded{0};  // bytes of the blocks recorded so far
  const int64_t limit;

  explicit Recording(int64_t limit) : limit(limit) {}
  Recording(const Recording&) = delete;
  Recording& operator=(const Recording&) = delete;
  ~Recording() {
    Spare<float>::instance().give(std::move(single));
    Spare<double>::instance().give(std::move(twice));
  }

  template <typename scalar_t>
  std::vector<TileRecord<scalar_t>>& tiles() {
    if constexpr (std::is_same_v<scalar_t, float>) {
      return single;
    } else {
      return twice;
    }
  }

  // Bytes held by the records (their vectors' capacity).
  int64_t bytes() const { return capacity_bytes(single) + capacity_bytes(twice); }

  int64_t tiles_kept() const {
    auto count = [](const auto& tiles) {
      return std::count_if(tiles.begin(), tiles.end(), [](const auto& tile) { return tile.kept; });
    };
    return count(single) + count(twice);
  }
};

// Per-pixel state of one tile, planar, rows padded by kLanes so a block never leaves its row;
// each worker owns one and reuses it for all its tiles.
template <typename scalar_t>
struct TileState {
  explicit TileState(int64_t tile_size) : stride(tile_size + kLanes) {
    for (std::vector<scalar_t>* plane : {&transmittance, &red, &green, &blue, &depth, &grad_red, &grad_green,
                                         &grad_blue, &grad_alpha, &grad_depth, &behind_red, &behind_green,
                                         &behind_blue, &behind_depth, &behind_transmittance}) {
      plane->assign(stride * tile_size, scalar_t(0));
    }
  }

  int64_t stride;
  std::vector<scalar_t> transmittance, red, green, blue, depth;
  TileRecord<scalar_t> scratch;  // the backward pass's own sweep, when the forward pass kept none
  std::vector<scalar_t> grad_red, grad_green, grad_blue, grad_alpha, grad_depth;
  std::vector<scalar_t> behind_red, behind_green, behind_blue, behind_depth, behind_transmittance;
};

// True when all kLanes values are below `limit`.
template <typename scalar_t>
inline bool all_below(const scalar_t* values, scalar_t limit) {
  scalar_t largest = values[0];
  for (int lane = 1; lane < kLanes; ++lane) {
    largest = std::max(largest, values[lane]);
  }
  return largest < limit;
}

// Composites one block of one Gaussian (spec step 6) into the tile's planes; returns how many
// pixels this block pushed below the early-termination threshold `stop`. With kRecord, writes the
// G actually used (0 for lanes that take no part) and each lane's T_i into `taken`, `front`.
template <typename scalar_t, bool kRecord>
inline int32_t composite_block(const scalar_t* __restrict gauss, scalar_t opacity, scalar_t alpha_max, scalar_t stop,
                               const scalar_t* color, scalar_t depth, scalar_t* __restrict transmittance,
                               scalar_t* __restrict red, scalar_t* __restrict green, scalar_t* __restrict blue,
                               scalar_t* __restrict out_depth, scalar_t* __restrict taken,
                               scalar_t* __restrict front) {
  const scalar_t r = color[0], g = color[1], b = color[2];
  int32_t stopped = 0;
#pragma omp simd reduction(+ : stopped)
  for (int lane = 0; lane < kLanes; ++lane) {
    const scalar_t t = transmittance[lane];
    const scalar_t used = t >= stop ? gauss[lane] : scalar_t(0);  // early termination (stop 0: never)
    const scalar_t alpha = std::min(opacity * used, alpha_max);
    const scalar_t weight = alpha * t;
    red[lane] += weight * r;
    green[lane] += weight * g;
    blue[lane] += weight * b;
    out_depth[lane] += weight * depth;
    const scalar_t next = t * (1 - alpha);
    transmittance[lane] = next;
    stopped += (t >= stop) & (next < stop);
    if (kRecord) {
      taken[lane] = used;
      front[lane] = t;
    }
  }
  return stopped;
}

// Spec steps 5-6 over the tile's front-to-back list ids[begin, end). With kRecord, every block
// is remembered in `record` for backward_tile() and no early exit is taken (the Gaussians past
// it composite nothing, so the planes are the same either way).
template <typename scalar_t, bool kRecord>
void composite_tile(const Inputs<scalar_t>& in, const int32_t* ids, int64_t begin, int64_t end, const Tile& tile,
                    const Settings& s, TileState<scalar_t>& state, TileRecord<scalar_t>* record) {
  std::fill(state.transmittance.begin(), state.transmittance.end(), scalar_t(1));
  for (std::vector<scalar_t>* plane : {&state.red, &state.green, &state.blue, &state.depth}) {
    std::fill(plane->begin(), plane->end(), scalar_t(0));
  }
  if (kRecord) {
    record->blocks.clear();
    record->first_block.clear();
  }
  const scalar_t cutoff = static_cast<scalar_t>(s.alpha_cutoff);
  const scalar_t alpha_max = static_cast<scalar_t>(s.alpha_max);
  const scalar_t stop = static_cast<scalar_t>(s.transmittance_stop);
  const int64_t tile_pixels = tile.width * tile.height;
  int64_t finished = 0;  // pixels whose T fell below `stop` (never counted when stop is 0)
  for (int64_t entry = begin; entry < end; ++entry) {
    const int64_t g = ids[entry];
    const Splat<scalar_t> splat = make_splat(in, g, tile, s);
    const scalar_t* color = in.colors + 3 * g;
    const scalar_t depth = in.depths[g];
    if (kRecord) {
      record->first_block.push_back(static_cast<int64_t>(record->blocks.size()));
    }
    for_each_block(splat, [&](int32_t row, int32_t col, int32_t last) {
      const int64_t pixel = row * state.stride + col;
      if (stop > 0 && all_below(&state.transmittance[pixel], stop)) {
        return;  // every lane has terminated: the block would composite nothing
      }
      scalar_t gauss[kLanes];
      block_gauss(splat, row, col, last, cutoff, gauss);
      Block<scalar_t> block;
      finished += composite_block<scalar_t, kRecord>(
          gauss, splat.opacity, alpha_max, stop, color, depth, &state.transmittance[pixel], &state.red[pixel],
          &state.green[pixel], &state.blue[pixel], &state.depth[pixel], block.gauss, block.transmittance);
      if (kRecord) {
        block.row = row;
        block.col = col;
        record->blocks.push_back(block);
      }
    });
    if (!kRecord && finished == tile_pixels) {
      break;
    }
  }
  if (kRecord) {
    record->first_block.push_back(static_cast<int64_t>(record->blocks.size()));
  }
}

template <typename scalar_t>
void write_tile(const Tile& tile, const Settings& s, const scalar_t* background, const TileState<scalar_t>& state,
                scalar_t* rgb, scalar_t* alpha, scalar_t* depth) {
  for (int64_t row = 0; row < tile.height; ++row) {
    for (int64_t col = 0; col < tile.width; ++col) {
      const int64_t pixel = row * state.stride + col;
      const int64_t out = (tile.image * s.height + tile.y0 + row) * s.width + tile.x0 + col;
      const scalar_t transmittance = state.transmittance[pixel];
      rgb[3 * out] = state.red[pixel] + transmittance * background[0];
      rgb[3 * out + 1] = state.green[pixel] + transmittance * background[1];
      rgb[3 * out + 2] = state.blue[pixel] + transmittance * background[2];
      alpha[out] = 1 - transmittance;
      depth[out] = state.depth[pixel];
    }
  }
}
// Back to front over the recorded blocks of one tile (`record`: the forward pass's; null: swept
// again here). For Gaussian i at a pixel, with the
// colour C_b, depth D_b and transmittance T_b composited behind it (C_b starts as the background):
//   d rgb / d alpha_i = T_i (c_i - C_b),  d alpha_out / d alpha_i = T_i T_b,
//   d depth / d alpha_i = T_i (z_i - D_b),  and d / d c_i = d / d z_i = alpha_i T_i.
// Lanes with G = 0 contribute exactly zero and leave the "behind" state unchanged.
template <typename scalar_t>
void backward_tile(const Inputs<scalar_t>& in, const int32_t* ids, int64_t begin, int64_t end, const Tile& tile,
                   const Settings& s, const scalar_t* v_rgb, const scalar_t* v_alpha, const scalar_t* v_depth,
                   TileState<scalar_t>& state, const TileRecord<scalar_t>* record, double* slots) {
  if (record == nullptr) {
    composite_tile<scalar_t, true>(in, ids, begin, end, tile, s, state, &state.scratch);
    record = &state.scratch;
  }
  const int64_t stride = state.stride;
  for (int64_t row = 0; row < tile.height; ++row) {
    for (int64_t col = 0; col < tile.width; ++col) {
      const int64_t pixel = row * stride + col;
      const int64_t out = (tile.image * s.height + tile.y0 + row) * s.width + tile.x0 + col;
      state.grad_red[pixel] = v_rgb[3 * out];
      state.grad_green[pixel] = v_rgb[3 * out + 1];
      state.grad_blue[pixel] = v_rgb[3 * out + 2];
      state.grad_alpha[pixel] = v_alpha[out];
      state.grad_depth[pixel] = v_depth[out];
    }
  }
  std::fill(state.behind_red.begin(), state.behind_red.end(), in.background[0]);
  std::fill(state.behind_green.begin(), state.behind_green.end(), in.background[1]);
  std::fill(state.behind_blue.begin(), state.behind_blue.end(), in.background[2]);
  std::fill(state.behind_depth.begin(), state.behind_depth.end(), scalar_t(0));
  std::fill(state.behind_transmittance.begin(), state.behind_transmittance.end(), scalar_t(1));
  const scalar_t alpha_max = static_cast<scalar_t>(s.alpha_max);
  const scalar_t half = static_cast<scalar_t>(0.5);
  for (int64_t entry = end - 1; entry >= begin; --entry) {
    const int64_t g = ids[entry];
    const Splat<scalar_t> splat = make_splat(in, g, tile, s);
    const scalar_t red = in.colors[3 * g], green = in.colors[3 * g + 1], blue = in.colors[3 * g + 2];
    const scalar_t depth = in.depths[g];
    scalar_t lanes[kNumGrads][kLanes] = {};  // per-lane partial sums, reduced once per Gaussian
    const int64_t first = record->first_block[entry - begin];
    for (int64_t index = record->first_block[entry - begin + 1] - 1; index >= first; --index) {
      const Block<scalar_t>& block = record->blocks[index];
      const int64_t pixel = block.row * stride + block.col;
      const scalar_t* __restrict g_red = &state.grad_red[pixel];
      const scalar_t* __restrict g_green = &state.grad_green[pixel];
      const scalar_t* __restrict g_blue = &state.grad_blue[pixel];
      const scalar_t* __restrict g_alpha = &state.grad_alpha[pixel];
      const scalar_t* __restrict g_depth = &state.grad_depth[pixel];
      scalar_t* __restrict b_red = &state.behind_red[pixel];
      scalar_t* __restrict b_green = &state.behind_green[pixel];
      scalar_t* __restrict b_blue = &state.behind_blue[pixel];
      scalar_t* __restrict b_depth = &state.behind_depth[pixel];
      scalar_t* __restrict b_transmittance = &state.behind_transmittance[pixel];
      const scalar_t dy = static_cast<scalar_t>(block.row) + half - splat.v;
    #pragma omp simd
      for (int lane = 0; lane < kLanes; ++lane) {
        const scalar_t gauss = block.gauss[lane];
        const scalar_t t = block.transmittance[lane];
        const scalar_t raw_alpha = splat.opacity * gauss;
        const scalar_t alpha = std::min(raw_alpha, alpha_max);
        const scalar_t weight = alpha * t;
        lanes[kRed][lane] += weight * g_red[lane];
        lanes[kGreen][lane] += weight * g_green[lane];
        lanes[kBlue][lane] += weight * g_blue[lane];
        lanes[kDepth][lane] += weight * g_depth[lane];
        const scalar_t v_alpha_i = t * ((red - b_red[lane]) * g_red[lane] + (green - b_green[lane]) * g_green[lane] +
                                        (blue - b_blue[lane]) * g_blue[lane] + b_transmittance[lane] * g_alpha[lane] +
                                        (depth - b_depth[lane]) * g_depth[lane]);
        const scalar_t keep = 1 - alpha;
        b_red[lane] = alpha * red + keep * b_red[lane];
        b_green[lane] = alpha * green + keep * b_green[lane];
        b_blue[lane] = alpha * blue + keep * b_blue[lane];
        b_depth[lane] = alpha * depth + keep * b_depth[lane];
        b_transmittance[lane] *= keep;
        // min(ALPHA_MAX, .) passes no gradient where it clamps.
        const scalar_t v_raw = raw_alpha < alpha_max ? v_alpha_i : scalar_t(0);
        lanes[kOpacity][lane] += v_raw * gauss;
        const scalar_t v_q = -half * raw_alpha * v_raw;  // d alpha / d q = -alpha / 2
        const scalar_t dx = static_cast<scalar_t>(block.col + lane) + half - splat.u;
        lanes[kConicA][lane] += v_q * dx * dx;
        lanes[kConicB][lane] += 2 * v_q * dx * dy;
        lanes[kConicC][lane] += v_q * dy * dy;
        // d = centre - (u, v), so d q / d u = -2 (a dx + b dy) and d q / d v = -2 (b dx + c dy).
        lanes[kU][lane] -= 2 * v_q * (splat.a * dx + splat.b * dy);
        lanes[kV][lane] -= 2 * v_q * (splat.b * dx + splat.c * dy);
      }
    }
    double* slot = slots + kNumGrads * entry;
    for (int k = 0; k < kNumGrads; ++k) {
      slot[k] = 0;
    #pragma omp simd
      for (int lane = 0; lane < kLanes; ++lane) {
        slot[k] += lanes[k][lane];
      }
    }
  }
}

// Counting sort of the (tile, Gaussian) pairs by tile. Gaussians are visited in each image's
// depth order, so each tile's list comes out front to back. Returns (offsets, ids): the list of
// tile t is ids[offsets[t], offsets[t + 1]), of flat Gaussian indices b N + n.
std::pair<at::Tensor, at::Tensor> bin_gaussians(const int32_t* bbox, const int32_t* order, const int64_t* counts,
                                                const Settings& s) {
  const int64_t ts = s.tile_size;
  auto offsets = at::zeros({s.num_tiles() + 1}, at::kLong);
  int64_t* offset = offsets.data_ptr<int64_t>();
  auto for_each_pair = [&](auto&& visit) {
    for (int64_t image = 0; image < s.batch; ++image) {
      for (int64_t i = 0; i < counts[image]; ++i) {
        const int64_t g = image * s.num_gaussians + order[image * s.num_gaussians + i];
        const int32_t* box = bbox + 4 * g;
        for (int64_t ty = box[2] / ts; ty <= box[3] / ts; ++ty) {
          for (int64_t tx = box[0] / ts; tx <= box[1] / ts; ++tx) {
            visit(image * s.tiles_per_image() + ty * s.tiles_x + tx, g);
          }
        }
      }
    }
  };
  for_each_pair([&](int64_t tile, int64_t) { ++offset[tile + 1]; });
  std::partial_sum(offset, offset + s.num_tiles() + 1, offset);
  auto ids = at::empty({offset[s.num_tiles()]}, at::kInt);
  int32_t* id = ids.data_ptr<int32_t>();
  std::vector<int64_t> cursor(offset, offset + s.num_tiles());
  for_each_pair([&](int64_t tile, int64_t g) { id[cursor[tile]++] = static_cast<int32_t>(g); });
  return {offsets, ids};
}

// Runs work(tile, state) for every tile on at::get_num_threads() workers, longest lists first.
template <typename scalar_t, typename Work>
void for_each_tile(const Settings& s, const int64_t* offsets, Work&& work) {
  std::vector<int64_t> tiles(s.num_tiles());
  std::iota(tiles.begin(), tiles.end(), 0);
  std::stable_sort(tiles.begin(), tiles.end(), [&](int64_t x, int64_t y) {
    return offsets[x + 1] - offsets[x] > offsets[y + 1] - offsets[y];
  });
  std::atomic<int64_t> next{0};
  const int64_t workers = std::max<int64_t>(1, std::min<int64_t>(at::get_num_threads(), s.num_tiles()));
  at::parallel_for(0, workers, 1, [&](int64_t, int64_t) {
    TileState<scalar_t> state(s.tile_size);
    for (int64_t i = next++; i < s.num_tiles(); i = next++) {
      work(tile_at(tiles[i], s), tiles[i], state);
    }
  });
}

Settings make_settings(const at::Tensor& opacities, int64_t width, int64_t height, int64_t tile_size,
                       double alpha_cutoff, double alpha_max, double transmittance_stop) {
  TORCH_CHECK(tile_size > 0, "tile_size must be positive");
  const int64_t tiles_x = (width + tile_size - 1) / tile_size;
  const int64_t tiles_y = (height + tile_size - 1) / tile_size;
  return {opacities.size(0), opacities.size(1), width, height, tile_size, tiles_x, tiles_y,
          alpha_cutoff, alpha_max, transmittance_stop};
}

template <typename scalar_t>
Inputs<scalar_t> make_inputs(const std::vector<at::Tensor>& gaussians) {
  TORCH_CHECK(gaussians.size() == 8, "expected means2d, conics, colors, opacities, depths, background, bbox, radius2");
  for (const at::Tensor& tensor : gaussians) {
    TORCH_CHECK(tensor.is_contiguous() && tensor.device().is_cpu(), "splat inputs must be contiguous CPU tensors");
  }
  const at::Tensor &means2d = gaussians[0], &conics = gaussians[1], &bbox = gaussians[6], &radius2 = gaussians[7];
  TORCH_CHECK(means2d.scalar_type() == at::kDouble && conics.scalar_type() == at::kDouble &&
                  radius2.scalar_type() == at::kDouble,
              "means2d, conics, radius2 must be float64");
  TORCH_CHECK(bbox.scalar_type() == at::kInt, "bbox must be int32");
  for (int index : {2, 3, 4, 5}) {
    TORCH_CHECK(gaussians[index].scalar_type() == gaussians[2].scalar_type(),
                "colors, opacities, depths and background must share one dtype");
  }
  return {means2d.data_ptr<double>(),         conics.data_ptr<double>(),        gaussians[2].data_ptr<scalar_t>(),
          gaussians[3].data_ptr<scalar_t>(), gaussians[4].data_ptr<scalar_t>(), bbox.data_ptr<int32_t>(),
          radius2.data_ptr<double>(),         gaussians[5].data_ptr<scalar_t>()};
}

using ForwardResult = std::tuple<at::Tensor, at::Tensor, at::Tensor, at::Tensor, at::Tensor, std::shared_ptr<Recording>>;

template <typename scalar_t>
ForwardResult forward_impl(const Inputs<scalar_t>& in, const at::Tensor& order, const at::Tensor& counts,
                           const Settings& s, int64_t record_bytes) {
  const std::pair<at::Tensor, at::Tensor> bins =
      bin_gaussians(in.bbox, order.data_ptr<int32_t>(), counts.data_ptr<int64_t>(), s);
  const at::Tensor& offsets = bins.first;
  const at::Tensor& ids = bins.second;
  const auto options = at::TensorOptions().dtype(c10::CppTypeToScalarType<scalar_t>::value);
  at::Tensor rgb = at::empty({s.batch, s.height, s.width, 3}, options);
  at::Tensor alpha = at::empty({s.batch, s.height, s.width}, options);
  at::Tensor depth = at::empty({s.batch, s.height, s.width}, options);
  const int64_t* offset = offsets.data_ptr<int64_t>();
  const int32_t* id = ids.data_ptr<int32_t>();
  scalar_t* rgb_out = rgb.data_ptr<scalar_t>();
  scalar_t* alpha_out = alpha.data_ptr<scalar_t>();
  scalar_t* depth_out = depth.data_ptr<scalar_t>();
  std::shared_ptr<Recording> recording = record_bytes > 0 ? std::make_shared<Recording>(record_bytes) : nullptr;
  std::vector<TileRecord<scalar_t>>* records = nullptr;
  if (recording) {
    records = &recording->tiles<scalar_t>();
    *records = Spare<scalar_t>::instance().take();
    records->resize(s.num_tiles());
    for (TileRecord<scalar_t>& record : *records) {
      record.kept = false;  // a spare's tiles were another pass's
    }
  }
  for_each_tile<scalar_t>(s, offset, [&](const Tile& tile, int64_t index, TileState<scalar_t>& state) {
    if (recording && recording->recorded.load() < recording->limit) {
      TileRecord<scalar_t>& record = (*records)[index];
      composite_tile<scalar_t, true>(in, id, offset[index], offset[index + 1], tile, s, state, &record);
      record.kept = true;
      recording->recorded += static_cast<int64_t>(record.blocks.size() * sizeof(Block<scalar_t>));
    } else {
      composite_tile<scalar_t, false>(in, id, offset[index], offset[index + 1], tile, s, state, nullptr);
    }
    write_tile(tile, s, in.background, state, rgb_out, alpha_out, depth_out);
  });
  return {rgb, alpha, depth, offsets, ids, recording};
}

template <typename scalar_t>
at::Tensor backward_impl(const Inputs<scalar_t>& in, const at::Tensor& offsets, const at::Tensor& ids,
                         const at::Tensor& v_rgb, const at::Tensor& v_alpha, const at::Tensor& v_depth,
                         const Settings& s, Recording* recording) {
  const int64_t* offset = offsets.data_ptr<int64_t>();
  const int32_t* id = ids.data_ptr<int32_t>();
  auto slots = at::empty({ids.size(0), kNumGrads}, at::kDouble);
  double* slot = slots.data_ptr<double>();
  const scalar_t* g_rgb = v_rgb.data_ptr<scalar_t>();
  const scalar_t* g_alpha = v_alpha.data_ptr<scalar_t>();
  const scalar_t* g_depth = v_depth.data_ptr<scalar_t>();
  const std::vector<TileRecord<scalar_t>>* records = recording ? &recording->tiles<scalar_t>() : nullptr;
  TORCH_CHECK(records == nullptr || static_cast<int64_t>(records->size()) == s.num_tiles(),
              "the recording is not of this forward pass");
  for_each_tile<scalar_t>(s, offset, [&](const Tile& tile, int64_t index, TileState<scalar_t>& state) {
    const TileRecord<scalar_t>* record = records && (*records)[index].kept ? &(*records)[index] : nullptr;
    backward_tile(in, id, offset[index], offset[index + 1], tile, s, g_rgb, g_alpha, g_depth, state, record, slot);
  });
  auto grads = at::zeros({s.batch, s.num_gaussians, kNumGrads}, at::kDouble);
  double* grad = grads.data_ptr<double>();
  for (int64_t pair = 0; pair < ids.size(0); ++pair) {
    for (int k = 0; k < kNumGrads; ++k) {
      grad[kNumGrads * id[pair] + k] += slot[kNumGrads * pair + k];
    }
  }
  return grads;
}

// gaussians: means2d (B, N, 2) f64, conics (B, N, 3) f64, colors (B, N, 3), opacities (B, N), depths (B, N),
// background (3), bbox (B, N, 4) int32, radius2 (B, N) f64; colors..background float32 or float64.
// record_bytes > 0: keep the tiles' blocks for backward() while they take less than that (the
// recording is returned last; None for 0).
ForwardResult forward(const std::vector<at::Tensor>& gaussians, const at::Tensor& order, const at::Tensor& counts,
                      int64_t width, int64_t height, int64_t tile_size, double alpha_cutoff, double alpha_max,
                      double transmittance_stop, int64_t record_bytes) {
  TORCH_CHECK(order.scalar_type() == at::kInt && counts.scalar_type() == at::kLong, "order: int32, counts: int64");
  const Settings s =
      make_settings(gaussians[3], width, height, tile_size, alpha_cutoff, alpha_max, transmittance_stop);
  if (gaussians[2].scalar_type() == at::kFloat) {
    return forward_impl(make_inputs<float>(gaussians), order, counts, s, record_bytes);
  }
  TORCH_CHECK(gaussians[2].scalar_type() == at::kDouble, "colors must be float32 or float64");
  return forward_impl(make_inputs<double>(gaussians), order, counts, s, record_bytes);
}

at::Tensor backward(const std::vector<at::Tensor>& gaussians, const at::Tensor& offsets, const at::Tensor& ids,
                    const at::Tensor& v_rgb, const at::Tensor& v_alpha, const at::Tensor& v_depth, int64_t width,
                    int64_t height, int64_t tile_size, double alpha_cutoff, double alpha_max,
                    double transmittance_stop, std::shared_ptr<Recording> recording) {
  for (const at::Tensor* tensor : {&v_rgb, &v_alpha, &v_depth}) {
    TORCH_CHECK(tensor->is_contiguous() && tensor->scalar_type() == gaussians[2].scalar_type(),
                "output gradients must be contiguous, in the colors' dtype");
  }
  const Settings s =
      make_settings(gaussians[3], width, height, tile_size, alpha_cutoff, alpha_max, transmittance_stop);
  if (gaussians[2].scalar_type() == at::kFloat) {
    return backward_impl(make_inputs<float>(gaussians), offsets, ids, v_rgb, v_alpha, v_depth, s, recording.get());
  }
  TORCH_CHECK(gaussians[2].scalar_type() == at::kDouble, "colors must be float32 or float64");
  return backward_impl(make_inputs<double>(gaussians), offsets, ids, v_rgb, v_alpha, v_depth, s, recording.get());
}

}  // namespace

PYBIND11_MODULE(TORCH_EXTENSION_NAME, module) {
  module.doc() = "pghm.splat native rasteriser (see pghm/splat/native.py)";
  pybind11::class_<Recording, std::shared_ptr<Recording>>(module, "Recording")
      .def_property_readonly("bytes", &Recording::bytes, "bytes the kept blocks take")
      .def_property_readonly("tiles_kept", &Recording::tiles_kept, "tiles whose blocks were kept");
  module.def("forward", &forward, "rgb, alpha, depth, tile offsets, tile ids, the recording (None for record_bytes 0)");
  module.def("backward", &backward, "(B, N, 10) float64 per-Gaussian gradients; recording: forward's, or None",
             pybind11::arg("gaussians"), pybind11::arg("offsets"), pybind11::arg("ids"), pybind11::arg("v_rgb"),
             pybind11::arg("v_alpha"), pybind11::arg("v_depth"), pybind11::arg("width"), pybind11::arg("height"),
             pybind11::arg("tile_size"), pybind11::arg("alpha_cutoff"), pybind11::arg("alpha_max"),
             pybind11::arg("transmittance_stop"), pybind11::arg("recording").none(true));
  module.attr("NUM_GRADS") = static_cast<int>(kNumGrads);
}
