// gnsx fused inference kernels: the graph network's MLPs run in row tiles that stay in a core's L2 cache.
//
// The eager path writes and re-reads every intermediate of an MLP from memory (bias broadcast, product, ReLU,
// product, LayerNorm's passes, residual add), and on the node side its [2,300, 64] products are too small for
// two threads to split well. On a 2-core Xeon those passes and dispatches cost more than the products
// (docs/speed.md). Here a tile of rows (~TILE rows x 64 features, a few hundred KB) goes through the whole MLP
// in per-thread buffers; memory sees the inputs read once and the output written once. Products are MKL's sgemm
// (the Fortran symbol libtorch exports), called per tile on strided views of the weights, so nothing is copied.
//
// Two ops, both inference only (no autograd; gnsx/model/fused.py decides when they apply and
// tests/test_fused.py checks them against the eager path):
//
//   gnsx::mlp(inputs, first_weights, ...)      out = LN(MLP(sum_i inputs_i W_i^T + b)) (+ residual)
//       the encoders, phi_v on [sum_j m_ij, v_i] (split first layer, no concatenation) and the decoder;
//   gnsx::edge_step(receiver_term, sender_term, edge_attr, ...)
//       phi_e on receiver-sorted edges from its first layer's per-node terms (gathered per edge), the sum of
//       the messages per receiver while the tile is in cache, and the edge update e' = m or e + m.
#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <torch/library.h>

#include <algorithm>
#include <cmath>
#include <vector>

extern "C" void sgemm_(const char* transa, const char* transb, const int* m, const int* n, const int* k,
                       const float* alpha, const float* a, const int* lda, const float* b, const int* ldb,
                       const float* beta, float* c, const int* ldc);

namespace {

// C[n, H] (row-major, row stride ldc) = beta * C + A[n, K] (row-major, lda) @ W[H, K]^T (row-major, ldw).
// Row-major C is column-major C^T = W A^T: sgemm with W transposed.
inline void rows_times_weight_t(int64_t n, int64_t H, int64_t K, const float* A, int64_t lda, const float* W,
                                int64_t ldw, float beta, float* C, int64_t ldc) {
  if (n == 0) return;
  const char trans = 'T', no_trans = 'N';
  const float one = 1.0f;
  const int ni = static_cast<int>(n), Hi = static_cast<int>(H), Ki = static_cast<int>(K);
  const int ldai = static_cast<int>(lda), ldwi = static_cast<int>(ldw), ldci = static_cast<int>(ldc);
  sgemm_(&trans, &no_trans, &Hi, &ni, &Ki, &one, W, &ldwi, A, &ldai, &beta, C, &ldci);
}

void check_matrix(const at::Tensor& t, const char* name, int64_t cols) {
  TORCH_CHECK(t.dim() == 2 && t.scalar_type() == at::kFloat && t.stride(1) == 1 && t.size(1) == cols &&
                  t.device().is_cpu(),
              "gnsx fused: ", name, " must be a CPU float32 [*, ", cols, "] matrix with unit column stride, got ",
              t.sizes(), " strides ", t.strides());
}

void check_vector(const at::Tensor& t, const char* name, int64_t size) {
  TORCH_CHECK(t.dim() == 1 && t.scalar_type() == at::kFloat && t.is_contiguous() && t.size(0) == size,
              "gnsx fused: ", name, " must be a contiguous float32 [", size, "] vector, got ", t.sizes());
}

inline void relu_(float* __restrict__ x, int64_t count) {
#pragma omp simd
  for (int64_t i = 0; i < count; ++i) x[i] = x[i] > 0.0f ? x[i] : 0.0f;
}

inline void fill_rows(float* __restrict__ out, const float* __restrict__ bias, int64_t n, int64_t width) {
  for (int64_t r = 0; r < n; ++r) {
    float* __restrict__ row = out + r * width;
#pragma omp simd
    for (int64_t c = 0; c < width; ++c) row[c] = bias[c];
  }
}

// Inputs with at most this many columns skip sgemm: with K = 3 a [n, 3] x [3, H] product is a write of the
// output with 3 multiply-adds per element, which a plain loop does at memory speed and sgemm does not.
constexpr int64_t kSmallK = 8;

// C[n, H] += A[n, K] (row-major, lda) @ Wt[K, H] (contiguous), for small K.
inline void small_k_product(int64_t n, int64_t H, int64_t K, const float* A, int64_t lda,
                            const float* __restrict__ Wt, float* C) {
  for (int64_t r = 0; r < n; ++r) {
    float* __restrict__ row = C + r * H;
    const float* a = A + r * lda;
    for (int64_t k = 0; k < K; ++k) {
      const float ak = a[k];
      const float* __restrict__ w = Wt + k * H;
#pragma omp simd
      for (int64_t c = 0; c < H; ++c) row[c] += ak * w[c];
    }
  }
}

// LayerNorm over each row of x + bias ([n, width], in place; biased variance, as torch.nn.LayerNorm); each
// row is in L1 after the first pass.
inline void layer_norm_rows(float* x, int64_t n, int64_t width, const float* __restrict__ bias,
                            const float* __restrict__ gamma, const float* __restrict__ beta, float eps) {
  const float inv_width = 1.0f / static_cast<float>(width);
  for (int64_t r = 0; r < n; ++r) {
    float* __restrict__ row = x + r * width;
    float mean = 0.0f;
#pragma omp simd reduction(+ : mean)
    for (int64_t c = 0; c < width; ++c) {
      row[c] += bias[c];
      mean += row[c];
    }
    mean *= inv_width;
    float var = 0.0f;
#pragma omp simd reduction(+ : var)
    for (int64_t c = 0; c < width; ++c) var += (row[c] - mean) * (row[c] - mean);
    const float inv = 1.0f / std::sqrt(var * inv_width + eps);
#pragma omp simd
    for (int64_t c = 0; c < width; ++c) row[c] = (row[c] - mean) * inv * gamma[c] + beta[c];
  }
}

// The MLP after its first layer's pre-activation: the weights as raw pointers, shared by both ops.
struct Tail {
  int64_t hidden = 0, out = 0;
  std::vector<const float*> w, b;  // further hidden layers [hidden, hidden], [hidden]
  std::vector<int64_t> ldw;
  const float* w_out = nullptr;  // [out, hidden], row stride ld_out
  int64_t ld_out = 0;
  const float* b_out = nullptr;
  const float* gamma = nullptr;  // LayerNorm, or nullptr
  const float* beta = nullptr;
  float eps = 0.0f;

  Tail(int64_t hidden_size, at::TensorList hidden_weights, at::TensorList hidden_biases, const at::Tensor& w_o,
       const at::Tensor& b_o, const c10::optional<at::Tensor>& g, const c10::optional<at::Tensor>& bt,
       double epsilon)
      : hidden(hidden_size), out(w_o.size(0)), eps(static_cast<float>(epsilon)) {
    TORCH_CHECK(hidden_weights.size() == hidden_biases.size(), "gnsx fused: hidden weights and biases differ");
    for (size_t k = 0; k < hidden_weights.size(); ++k) {
      check_matrix(hidden_weights[k], "hidden weight", hidden);
      TORCH_CHECK(hidden_weights[k].size(0) == hidden, "gnsx fused: hidden weights must be square");
      check_vector(hidden_biases[k], "hidden bias", hidden);
      w.push_back(hidden_weights[k].data_ptr<float>());
      ldw.push_back(hidden_weights[k].stride(0));
      b.push_back(hidden_biases[k].data_ptr<float>());
    }
    check_matrix(w_o, "output weight", hidden);
    check_vector(b_o, "output bias", out);
    w_out = w_o.data_ptr<float>();
    ld_out = w_o.stride(0);
    b_out = b_o.data_ptr<float>();
    TORCH_CHECK(g.has_value() == bt.has_value(), "gnsx fused: LayerNorm needs both gamma and beta");
    if (g.has_value()) {
      check_vector(*g, "LayerNorm weight", out);
      check_vector(*bt, "LayerNorm bias", out);
      gamma = g->data_ptr<float>();
      beta = bt->data_ptr<float>();
    }
  }

  // h[n, hidden] holds the first layer's pre-activation; writes the MLP's output rows to out_rows[n, out].
  // scratch: [n, hidden] when there are further hidden layers.
  void run(float* h, float* scratch, int64_t n, float* out_rows) const {
    relu_(h, n * hidden);
    for (size_t k = 0; k < w.size(); ++k) {
      fill_rows(scratch, b[k], n, hidden);
      rows_times_weight_t(n, hidden, hidden, h, hidden, w[k], ldw[k], 1.0f, scratch, hidden);
      std::copy(scratch, scratch + n * hidden, h);
      relu_(h, n * hidden);
    }
    if (gamma != nullptr) {  // the output bias joins LayerNorm's first pass instead of a pass of its own
      rows_times_weight_t(n, out, hidden, h, hidden, w_out, ld_out, 0.0f, out_rows, out);
      layer_norm_rows(out_rows, n, out, b_out, gamma, beta, eps);
    } else {
      fill_rows(out_rows, b_out, n, out);
      rows_times_weight_t(n, out, hidden, h, hidden, w_out, ld_out, 1.0f, out_rows, out);
    }
  }
};

at::Tensor mlp(at::TensorList inputs, at::TensorList first_weights, const at::Tensor& first_bias,
               at::TensorList hidden_weights, at::TensorList hidden_biases, const at::Tensor& w_out,
               const at::Tensor& b_out, const c10::optional<at::Tensor>& gamma,
               const c10::optional<at::Tensor>& beta, double eps, const c10::optional<at::Tensor>& residual,
               int64_t tile_rows) {
  TORCH_CHECK(!inputs.empty() && inputs.size() == first_weights.size(),
              "gnsx::mlp: one first-layer weight block per input");
  const int64_t M = inputs[0].size(0), H = first_bias.size(0);
  check_vector(first_bias, "first bias", H);
  for (size_t i = 0; i < inputs.size(); ++i) {
    check_matrix(inputs[i], "input", inputs[i].size(1));
    TORCH_CHECK(inputs[i].size(0) == M, "gnsx::mlp: inputs have different row counts");
    check_matrix(first_weights[i], "first weight", inputs[i].size(1));
    TORCH_CHECK(first_weights[i].size(0) == H, "gnsx::mlp: first weight rows must equal the bias size");
  }
  const Tail tail(H, hidden_weights, hidden_biases, w_out, b_out, gamma, beta, eps);
  const float* res = nullptr;
  int64_t ld_res = 0;
  if (residual.has_value()) {
    check_matrix(*residual, "residual", tail.out);
    TORCH_CHECK(residual->size(0) == M, "gnsx::mlp: residual rows");
    res = residual->data_ptr<float>();
    ld_res = residual->stride(0);
  }
  auto out = at::empty({M, tail.out}, inputs[0].options());
  float* o = out.data_ptr<float>();
  const float* b1 = first_bias.data_ptr<float>();
  // First-layer blocks with few columns (the edge encoder's D + 1 = 3 features) as [K, H] for small_k_product.
  std::vector<std::vector<float>> transposed(inputs.size());
  for (size_t i = 0; i < inputs.size(); ++i) {
    const int64_t K = inputs[i].size(1);
    if (K > kSmallK) continue;
    const float* w = first_weights[i].data_ptr<float>();
    const int64_t ldw = first_weights[i].stride(0);
    transposed[i].resize(K * H);
    for (int64_t k = 0; k < K; ++k)
      for (int64_t c = 0; c < H; ++c) transposed[i][k * H + c] = w[c * ldw + k];
  }
  const int64_t num_tiles = (M + tile_rows - 1) / tile_rows;
  at::parallel_for(0, num_tiles, 1, [&](int64_t tile_begin, int64_t tile_end) {
    std::vector<float> hidden(tile_rows * H), scratch(tail.w.empty() ? 0 : tile_rows * H);
    for (int64_t tile = tile_begin; tile < tile_end; ++tile) {
      const int64_t r0 = tile * tile_rows, n = std::min(tile_rows, M - r0);
      float* h = hidden.data();
      fill_rows(h, b1, n, H);
      for (size_t i = 0; i < inputs.size(); ++i) {
        const int64_t K = inputs[i].size(1), lda = inputs[i].stride(0);
        const float* in = inputs[i].data_ptr<float>() + r0 * lda;
        if (K <= kSmallK) {
          small_k_product(n, H, K, in, lda, transposed[i].data(), h);
        } else {
          rows_times_weight_t(n, H, K, in, lda, first_weights[i].data_ptr<float>(), first_weights[i].stride(0),
                              1.0f, h, H);
        }
      }
      float* rows = o + r0 * tail.out;
      tail.run(h, scratch.data(), n, rows);
      if (res != nullptr) {
        for (int64_t r = 0; r < n; ++r) {
          const float* __restrict__ in = res + (r0 + r) * ld_res;
          float* __restrict__ row = rows + r * tail.out;
#pragma omp simd
          for (int64_t c = 0; c < tail.out; ++c) row[c] += in[c];
        }
      }
    }
  });
  return out;
}

std::tuple<at::Tensor, at::Tensor> edge_step(const at::Tensor& receiver_term, const at::Tensor& sender_term,
                                             const at::Tensor& edge_attr, const at::Tensor& senders,
                                             const at::Tensor& receivers, const at::Tensor& offsets,
                                             const at::Tensor& w_edge, at::TensorList hidden_weights,
                                             at::TensorList hidden_biases, const at::Tensor& w_out,
                                             const at::Tensor& b_out, const at::Tensor& gamma,
                                             const at::Tensor& beta, double eps, bool residual,
                                             int64_t tile_edges) {
  const int64_t R = receiver_term.size(0), H = receiver_term.size(1), L = w_out.size(0);
  const int64_t E = edge_attr.size(0);
  check_matrix(receiver_term, "receiver_term", H);
  check_matrix(sender_term, "sender_term", H);
  check_matrix(edge_attr, "edge_attr", L);
  check_matrix(w_edge, "w_edge", L);
  TORCH_CHECK(w_edge.size(0) == H, "gnsx::edge_step: w_edge must be [H, L]");
  TORCH_CHECK(edge_attr.stride(0) == L, "gnsx::edge_step: edge_attr must be row-contiguous");
  const Tail tail(H, hidden_weights, hidden_biases, w_out, b_out, gamma, beta, eps);
  TORCH_CHECK(tail.out == L, "gnsx::edge_step: phi_e must map to the edge latent size");
  TORCH_CHECK(senders.scalar_type() == at::kLong && receivers.scalar_type() == at::kLong &&
                  offsets.scalar_type() == at::kLong && senders.is_contiguous() && receivers.is_contiguous() &&
                  offsets.is_contiguous() && offsets.numel() >= R + 1,
              "gnsx::edge_step: senders, receivers, offsets must be contiguous int64, offsets >= R + 1 long");
  const int64_t* off = offsets.data_ptr<int64_t>();
  TORCH_CHECK(off[0] == 0 && off[R] == E, "gnsx::edge_step: offsets[R] must equal the edge count (", E,
              "), got ", off[R]);
  TORCH_CHECK(senders.numel() >= E && receivers.numel() >= E, "gnsx::edge_step: fewer indices than edges");

  // Tiles of whole receivers with ~tile_edges edges each (a receiver is never split: its sum stays in one tile).
  std::vector<int64_t> tile_start{0};
  int64_t max_tile = 0;
  for (int64_t r = 0, first = 0; r < R; ++r) {
    if (off[r + 1] - off[first] >= tile_edges || r == R - 1) {
      max_tile = std::max(max_tile, off[r + 1] - off[first]);
      tile_start.push_back(r + 1);
      first = r + 1;
    }
  }
  const int64_t num_tiles = static_cast<int64_t>(tile_start.size()) - 1;

  auto out_edges = at::empty({E, L}, edge_attr.options());
  auto aggregated = at::zeros({R, L}, edge_attr.options());
  const float* rt = receiver_term.data_ptr<float>();
  const float* st = sender_term.data_ptr<float>();
  const int64_t ld_rt = receiver_term.stride(0), ld_st = sender_term.stride(0);
  const float* ea = edge_attr.data_ptr<float>();
  const int64_t* snd = senders.data_ptr<int64_t>();
  const int64_t* rcv = receivers.data_ptr<int64_t>();
  const float* we = w_edge.data_ptr<float>();
  const int64_t ld_we = w_edge.stride(0);
  float* oe = out_edges.data_ptr<float>();
  float* agg = aggregated.data_ptr<float>();

  at::parallel_for(0, num_tiles, 1, [&](int64_t tile_begin, int64_t tile_end) {
    // Per-thread tile buffers, reused across this thread's tiles.
    std::vector<float> hidden(max_tile * H), scratch(tail.w.empty() ? 0 : max_tile * H);
    std::vector<float> messages(residual ? max_tile * L : 0);
    for (int64_t tile = tile_begin; tile < tile_end; ++tile) {
      const int64_t r0 = tile_start[tile], r1 = tile_start[tile + 1];
      const int64_t e0 = off[r0], n = off[r1] - e0;
      if (n == 0) continue;
      float* h = hidden.data();
      for (int64_t e = 0; e < n; ++e) {  // the first layer's node terms, gathered
        const float* __restrict__ a = rt + rcv[e0 + e] * ld_rt;
        const float* __restrict__ b = st + snd[e0 + e] * ld_st;
        float* __restrict__ row = h + e * H;
#pragma omp simd
        for (int64_t c = 0; c < H; ++c) row[c] = a[c] + b[c];
      }
      rows_times_weight_t(n, H, L, ea + e0 * L, L, we, ld_we, 1.0f, h, H);
      // The messages go straight into the output rows when the edge update is a replacement.
      float* m = residual ? messages.data() : oe + e0 * L;
      tail.run(h, scratch.data(), n, m);
      for (int64_t r = r0; r < r1; ++r) {  // sum per receiver, in edge order
        float* __restrict__ acc = agg + r * L;
        for (int64_t e = off[r]; e < off[r + 1]; ++e) {
          const float* __restrict__ row = m + (e - e0) * L;
#pragma omp simd
          for (int64_t c = 0; c < L; ++c) acc[c] += row[c];
        }
      }
      if (residual) {
        const float* __restrict__ in = ea + e0 * L;
        float* __restrict__ out = oe + e0 * L;
#pragma omp simd
        for (int64_t i = 0; i < n * L; ++i) out[i] = in[i] + m[i];
      }
    }
  });
  return {out_edges, aggregated};
}

}  // namespace

TORCH_LIBRARY(gnsx, m) {
  m.def(
      "mlp(Tensor[] inputs, Tensor[] first_weights, Tensor first_bias, Tensor[] hidden_weights, "
      "Tensor[] hidden_biases, Tensor w_out, Tensor b_out, Tensor? gamma, Tensor? beta, float eps, "
      "Tensor? residual, int tile_rows) -> Tensor");
  m.def(
      "edge_step(Tensor receiver_term, Tensor sender_term, Tensor edge_attr, Tensor senders, Tensor receivers, "
      "Tensor offsets, Tensor w_edge, Tensor[] hidden_weights, Tensor[] hidden_biases, Tensor w_out, "
      "Tensor b_out, Tensor gamma, Tensor beta, float eps, bool residual, int tile_edges) -> (Tensor, Tensor)");
}

TORCH_LIBRARY_IMPL(gnsx, CPU, m) {
  m.impl("mlp", &mlp);
  m.impl("edge_step", &edge_step);
}
