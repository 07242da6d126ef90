// LeafFit affine-MLS leaf deformer: GLSL 4.30 transcription of leaffit_usd/fit/mls.py.
// Keep it line by line in sync with mls_weights(); tests/runtime/test_glsl.py checks that the
// two agree within 1e-5 of the leaf size.
//
// Include this file after the #version line (GLSL >= 4.30: shader storage buffers), e.g. with
// leaffit_usd.runtime.shader.vertex_shader_source(), or paste it into your own shader.
//
// Formulation (row vectors; w_hat normalised weights, shifted exponentials):
//   d2_i = |v - p_i|^2;  w_i = exp(-(d2_i - min_k d2_k) / sigma^2);  w_hat_i = w_i / sum w
//   p*   = sum_i w_hat_i p_i;  p_hat_i = p_i - p*
//   P    = sum_i w_hat_i p_hat_i^T p_hat_i + (reg * sigma)^2 I            (3 x 3)
//   A_j  = w_hat_j * (1 + (v - p*) P^{-1} p_hat_j^T)
//   f(v) = sum_j A_j q_j
// The regulariser makes P invertible for a flat template (singular affine moment matrix); it
// must be the same `reg` as the CPU (stored on the stage with sigma).
//
// Data (all in the instance's local frame, template units):
//   LeafFitControls  binding LEAFFIT_CONTROLS_BINDING: vec4 p[K]        (xyz = p_j, w unused)
//   LeafFitTargets   binding LEAFFIT_TARGETS_BINDING:  vec4 q[L * K]    (instance i: q[i*K + j])
//   LeafFitWeights   binding LEAFFIT_WEIGHTS_BINDING:  float A[V * K]   (only for the
//                    precomputed-weights variant leaffit_mls_weighted; vertex v: A[v*K + j])
// std430 pads vec3 arrays to 16 bytes, hence vec4 storage.

#ifndef LEAFFIT_MAX_K
#define LEAFFIT_MAX_K 64
#endif
#ifndef LEAFFIT_CONTROLS_BINDING
#define LEAFFIT_CONTROLS_BINDING 0
#endif
#ifndef LEAFFIT_TARGETS_BINDING
#define LEAFFIT_TARGETS_BINDING 1
#endif
#ifndef LEAFFIT_WEIGHTS_BINDING
#define LEAFFIT_WEIGHTS_BINDING 2
#endif

layout(std430, binding = LEAFFIT_CONTROLS_BINDING) readonly buffer LeafFitControls {
    vec4 leaffit_p[];
};
layout(std430, binding = LEAFFIT_TARGETS_BINDING) readonly buffer LeafFitTargets {
    vec4 leaffit_q[];
};
#ifdef LEAFFIT_USE_WEIGHTS
layout(std430, binding = LEAFFIT_WEIGHTS_BINDING) readonly buffer LeafFitWeights {
    float leaffit_A[];
};
#endif

// Deform template vertex v (template local frame) by instance `instance`'s MLS field.
// K <= LEAFFIT_MAX_K control points, kernel width sigma, regulariser reg (mls.py's names).
// Returns the deformed point in the instance's local frame (before the instance transform).
vec3 leaffit_mls(vec3 v, int K, float sigma, float reg, int instance) {
    float w[LEAFFIT_MAX_K];
    // d2_i = |v - p_i|^2 and its minimum (the shift keeps exp() from underflowing)
    float d2min = 3.402823e38;
    for (int i = 0; i < K; ++i) {
        vec3 d = v - leaffit_p[i].xyz;
        w[i] = dot(d, d);
        d2min = min(d2min, w[i]);
    }
    // w_i = exp(-(d2_i - min d2) / sigma^2), then w_hat = w / sum w
    float wsum = 0.0;
    for (int i = 0; i < K; ++i) {
        w[i] = exp(-(w[i] - d2min) / (sigma * sigma));
        wsum += w[i];
    }
    // p* = sum w_hat_i p_i
    vec3 p_star = vec3(0.0);
    for (int i = 0; i < K; ++i) {
        w[i] /= wsum;
        p_star += w[i] * leaffit_p[i].xyz;
    }
    // P = sum w_hat_i p_hat_i^T p_hat_i + (reg sigma)^2 I
    mat3 P = mat3((reg * sigma) * (reg * sigma));
    for (int i = 0; i < K; ++i) {
        vec3 p_hat = leaffit_p[i].xyz - p_star;
        P += w[i] * outerProduct(p_hat, p_hat);
    }
    // x = P^-1 (v - p*)   (P is symmetric positive definite)
    vec3 x = inverse(P) * (v - p_star);
    // f(v) = sum_j A_j q_j,  A_j = w_hat_j (1 + p_hat_j . x)
    vec3 f = vec3(0.0);
    int base = instance * K;
    for (int j = 0; j < K; ++j) {
        float A = w[j] * (1.0 + dot(leaffit_p[j].xyz - p_star, x));
        f += A * leaffit_q[base + j].xyz;
    }
    return f;
}

#ifdef LEAFFIT_USE_WEIGHTS
// Variant with the (V, K) weights precomputed on the CPU (leaffit_usd.fit.mls.mls_weights, once
// per template): f(v) = sum_j A[vertex, j] q_j. Cheaper per vertex and float64-accurate weights.
vec3 leaffit_mls_weighted(int vertex, int K, int instance) {
    vec3 f = vec3(0.0);
    int base = instance * K;
    int row = vertex * K;
    for (int j = 0; j < K; ++j) {
        f += leaffit_A[row + j] * leaffit_q[base + j].xyz;
    }
    return f;
}
#endif
