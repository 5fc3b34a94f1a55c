//! The two preview meshes, in glTF's frame: +Y up, metres, counter-clockwise front
//! faces. The material plane maps to the ground: plane `(x, y, z)` cm is glTF
//! `(x, z, -y) / 100` m, so the material's top edge (largest y) faces away from a viewer
//! on +Z. Texture coordinates follow glTF (u right, v down the image), so map pixel
//! `(i, j)` lands where it lies on the plane, and tangents point along plane +x with
//! `w = +1` (bitangent = plane +y), matching the OpenGL-convention normal map.
use std::f64::consts::{PI, TAU};

use svbrdf_core::plane::Region;

/// An indexed triangle mesh.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    /// Positions, metres.
    pub positions: Vec<[f32; 3]>,
    /// Unit normals.
    pub normals: Vec<[f32; 3]>,
    /// Unit tangents (xyz) and handedness (w).
    pub tangents: Vec<[f32; 4]>,
    /// Texture coordinates (glTF: v grows downwards in the image).
    pub uvs: Vec<[f32; 2]>,
    /// Triangles.
    pub indices: Vec<u32>,
}

impl Mesh {
    /// Component-wise minimum and maximum of the positions.
    pub fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in &self.positions {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        (lo, hi)
    }
}

/// The material's own rectangle at its measured size, centred on the origin.
pub fn quad(region: &Region) -> Mesh {
    let (w, h) = (region.width() / 100.0, region.height() / 100.0);
    let (x0, x1) = (-0.5 * w, 0.5 * w);
    // Plane +y is glTF -Z: the top row (v = 0) is at the far edge, -Z.
    let (z_top, z_bottom) = (-0.5 * h, 0.5 * h);
    let p = |x: f64, z: f64| [x as f32, 0.0, z as f32];
    Mesh {
        positions: vec![p(x0, z_top), p(x1, z_top), p(x1, z_bottom), p(x0, z_bottom)],
        normals: vec![[0.0, 1.0, 0.0]; 4],
        tangents: vec![[1.0, 0.0, 0.0, 1.0]; 4],
        uvs: vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
        // Counter-clockwise seen from +Y.
        indices: vec![0, 2, 1, 0, 3, 2],
    }
}

/// A UV sphere of `radius` m centred at `centre`, textured at the material's physical
/// scale (the maps repeat around it: `u` spans `2 pi r / width` tiles).
pub fn sphere(region: &Region, radius: f64, centre: [f64; 3], segments: u32, rings: u32) -> Mesh {
    let (w, h) = (region.width() / 100.0, region.height() / 100.0);
    let u_tiles = TAU * radius / w;
    let v_tiles = PI * radius / h;
    let mut m = Mesh::default();
    for r in 0..=rings {
        let theta = PI * f64::from(r) / f64::from(rings);
        for s in 0..=segments {
            let phi = TAU * f64::from(s) / f64::from(segments);
            let n = [
                theta.sin() * phi.sin(),
                theta.cos(),
                theta.sin() * phi.cos(),
            ];
            m.positions.push([
                (centre[0] + radius * n[0]) as f32,
                (centre[1] + radius * n[1]) as f32,
                (centre[2] + radius * n[2]) as f32,
            ]);
            m.normals.push(n.map(|v| v as f32));
            // d position / d phi, normalised: eastward, (cos phi, 0, -sin phi).
            m.tangents
                .push([phi.cos() as f32, 0.0, (-phi.sin()) as f32, 1.0]);
            m.uvs.push([
                (u_tiles * f64::from(s) / f64::from(segments)) as f32,
                (v_tiles * f64::from(r) / f64::from(rings)) as f32,
            ]);
        }
    }
    let stride = segments + 1;
    for r in 0..rings {
        for s in 0..segments {
            let a = r * stride + s;
            let b = a + stride;
            // Counter-clockwise seen from outside (normal = position direction).
            m.indices.extend_from_slice(&[a, b, a + 1, a + 1, b, b + 1]);
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    fn face_normal(m: &Mesh, t: usize) -> [f32; 3] {
        let p = |k: usize| m.positions[m.indices[3 * t + k] as usize];
        let (a, b, c) = (p(0), p(1), p(2));
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ]
    }

    #[test]
    fn triangles_face_along_their_normals_and_tangents_follow_u() {
        let region = Region::centred(20.0, 10.0);
        for m in [
            quad(&region),
            sphere(&region, 0.05, [0.2, 0.05, 0.0], 16, 8),
        ] {
            for t in 0..m.indices.len() / 3 {
                let f = face_normal(&m, t);
                let len = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
                if len < 1e-9 {
                    continue; // collapsed triangles at the sphere's poles
                }
                let n = m.normals[m.indices[3 * t] as usize];
                assert!(
                    f[0] * n[0] + f[1] * n[1] + f[2] * n[2] > 0.0,
                    "triangle {t}"
                );
            }
            // Along a tangent, u grows.
            for (i, t) in m.tangents.iter().enumerate().take(m.positions.len() - 1) {
                let j = i + 1;
                let du = m.uvs[j][0] - m.uvs[i][0];
                let dp = [
                    m.positions[j][0] - m.positions[i][0],
                    m.positions[j][1] - m.positions[i][1],
                    m.positions[j][2] - m.positions[i][2],
                ];
                let along = dp[0] * t[0] + dp[1] * t[1] + dp[2] * t[2];
                if du > 0.0 && along.abs() > 1e-6 {
                    assert!(along > 0.0, "vertex {i}");
                }
            }
        }
    }

    #[test]
    fn quad_has_the_material_size_with_its_top_edge_at_minus_z() {
        let m = quad(&Region::centred(20.0, 10.0));
        let (lo, hi) = m.bounds();
        assert!((hi[0] - lo[0] - 0.2).abs() < 1e-6 && (hi[2] - lo[2] - 0.1).abs() < 1e-6);
        // uv (0, 0) is the map's top-left pixel: plane (x_min, y_max) -> glTF (-w/2, 0, -h/2).
        assert_eq!(m.uvs[0], [0.0, 0.0]);
        assert_eq!(m.positions[0], [-0.1, 0.0, -0.05]);
    }
}
