#version 430 core
// LeafFit minimal vertex shader: deforms the template leaf per instance (affine MLS, see
// leaffit_mls.glsl) and applies the PointInstancer transform
//     x_asset = position + rotate(orientation, scale * MLS(x))      (leaffit_usd/usd/asset.py)
// Draw the template mesh instanced, one instance per leaf (gl_InstanceID = leaf index j).
// `out_position` (model frame) is there for transform feedback / debugging.
// leaffit_usd.runtime.shader.vertex_shader_source() expands the include line below; define
// LEAFFIT_USE_WEIGHTS before it to use per-vertex precomputed weights instead.

// #leaffit_include "leaffit_mls.glsl"

layout(location = 0) in vec3 in_position;              // template vertex, template local frame
layout(location = 1) in vec3 in_instance_position;     // per instance (divisor 1), asset frame
layout(location = 2) in vec4 in_instance_orientation;  // per instance, quaternion (w, x, y, z)
layout(location = 3) in vec3 in_instance_scale;        // per instance

uniform int leaffit_K;              // number of control points (<= LEAFFIT_MAX_K)
uniform float leaffit_sigma;        // MLS kernel width (stage: leaffit:sigma)
uniform float leaffit_reg;          // MLS regulariser (stage: leaffit:reg)
uniform mat4 u_model;               // asset frame -> model/world frame (identity for asset frame)
uniform mat4 u_view_projection;     // world -> clip

out vec3 out_position;

#ifdef LEAFFIT_WIND
// Wind (leaffit_usd.usd.wind): leaf j turns about its axis through its pivot (instance local
// frame) by strength * sin(2 pi (frequency * time + phase_j)). Turning the K targets turns the
// evaluated point the same way (affine MLS is linear in the targets, its weights sum to 1), so
// the turn is applied here, after the MLS.
#ifndef LEAFFIT_WIND_BINDING
#define LEAFFIT_WIND_BINDING 3
#endif
layout(std430, binding = LEAFFIT_WIND_BINDING) readonly buffer LeafFitWind {
    vec4 leaffit_wind[];            // instance i: [2i] = (pivot xyz, phase), [2i+1] = (unit axis xyz, 0)
};
uniform float leaffit_wind_time;        // seconds
uniform float leaffit_wind_strength;    // radians
uniform float leaffit_wind_frequency;   // Hz

vec3 leaffit_apply_wind(vec3 p, int instance) {
    vec4 pp = leaffit_wind[2 * instance];
    vec3 u = leaffit_wind[2 * instance + 1].xyz;
    float a = leaffit_wind_strength * sin(6.283185307179586 * (leaffit_wind_frequency * leaffit_wind_time + pp.w));
    vec3 v = p - pp.xyz;
    float c = cos(a), s = sin(a);
    return pp.xyz + v * c + cross(u, v) * s + u * dot(u, v) * (1.0 - c);
}
#endif

// Rotate v by the quaternion q = (w, x, y, z) (normalised here, as USD does).
vec3 leaffit_rotate(vec4 q, vec3 v) {
    q = normalize(q);
    vec3 u = q.yzw;
    return v + 2.0 * cross(u, cross(u, v) + q.x * v);
}

void main() {
#ifdef LEAFFIT_USE_WEIGHTS
    vec3 local = leaffit_mls_weighted(gl_VertexID, leaffit_K, gl_InstanceID);
#else
    vec3 local = leaffit_mls(in_position, leaffit_K, leaffit_sigma, leaffit_reg, gl_InstanceID);
#endif
#ifdef LEAFFIT_WIND
    local = leaffit_apply_wind(local, gl_InstanceID);
#endif
    vec3 asset = in_instance_position
               + leaffit_rotate(in_instance_orientation, in_instance_scale * local);
    vec4 world = u_model * vec4(asset, 1.0);
    out_position = world.xyz;
    gl_Position = u_view_projection * world;
}
