//! Procedural objects for the embedded default dataset: a flat textured box, a labelled can
//! and a bottle (solid of revolution), plus the turntable disc. No external files.

use crate::error::SynthError;
use crate::mesh::TexturedMesh;
use crate::texture;
use nalgebra::Point3;
use std::f32::consts::TAU;
use std::path::PathBuf;
use std::sync::Arc;

/// Names accepted by [`procedural`].
pub const PROCEDURAL_NAMES: [&str; 3] = ["box", "can", "bottle"];

/// Build a procedural object by name, standing on `z = 0`, centred on the z axis.
pub fn procedural(name: &str, seed: u64) -> Result<TexturedMesh, SynthError> {
    match name {
        "box" => Ok(textured_box(0.16, 0.06, 0.22, seed)),
        "can" => Ok(revolved(name, &can_profile(0.034, 0.102), seed)),
        "bottle" => Ok(revolved(name, &bottle_profile(), seed)),
        _ => Err(SynthError::UnknownProcedural { name: name.into(), available: PROCEDURAL_NAMES.join(", ") }),
    }
}

#[derive(Default)]
struct Builder {
    positions: Vec<Point3<f32>>,
    uvs: Vec<[f32; 2]>,
    triangles: Vec<[u32; 3]>,
}

impl Builder {
    fn vertex(&mut self, p: Point3<f32>, uv: [f32; 2]) -> u32 {
        self.positions.push(p);
        self.uvs.push(uv);
        self.positions.len() as u32 - 1
    }

    /// A grid of `n x n` quads spanning `origin + s*du + t*dv`, `s, t in [0, 1]`, mapped to the
    /// UV rectangle `uv0 .. uv1`. Counter-clockwise seen from the side `du x dv` points to.
    fn grid(
        &mut self,
        origin: Point3<f32>,
        du: nalgebra::Vector3<f32>,
        dv: nalgebra::Vector3<f32>,
        uv0: [f32; 2],
        uv1: [f32; 2],
        n: u32,
    ) {
        let base = self.positions.len() as u32;
        for j in 0..=n {
            for i in 0..=n {
                let (s, t) = (i as f32 / n as f32, j as f32 / n as f32);
                self.vertex(origin + du * s + dv * t, [uv0[0] + (uv1[0] - uv0[0]) * s, uv0[1] + (uv1[1] - uv0[1]) * t]);
            }
        }
        let idx = |i: u32, j: u32| base + j * (n + 1) + i;
        for j in 0..n {
            for i in 0..n {
                self.triangles.push([idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)]);
                self.triangles.push([idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)]);
            }
        }
    }

    fn finish(self, name: &str, texture: image::RgbImage) -> TexturedMesh {
        TexturedMesh::new(
            PathBuf::from(format!("procedural:{name}")),
            self.positions,
            self.uvs,
            self.triangles,
            Arc::new(texture),
        )
        .expect("procedural meshes are valid by construction")
    }
}

/// A box `w x d x h` (x, y, z) standing on z = 0, each face its own cell of a 3x2 texture atlas.
fn textured_box(w: f32, d: f32, h: f32, seed: u64) -> TexturedMesh {
    use nalgebra::Vector3 as V;
    let mut b = Builder::default();
    let (x0, y0) = (-w / 2.0, -d / 2.0);
    let cell = |k: u32| {
        let (cx, cy) = ((k % 3) as f32 / 3.0, (k / 3) as f32 / 2.0);
        ([cx + 0.01, cy + 0.01], [cx + 1.0 / 3.0 - 0.01, cy + 0.5 - 0.01])
    };
    let n = 24;
    let faces = [
        (Point3::new(x0, y0, 0.0), V::new(w, 0.0, 0.0), V::new(0.0, 0.0, h)), // -y (front)
        (Point3::new(x0 + w, y0 + d, 0.0), V::new(-w, 0.0, 0.0), V::new(0.0, 0.0, h)), // +y (back)
        (Point3::new(x0 + w, y0, 0.0), V::new(0.0, d, 0.0), V::new(0.0, 0.0, h)), // +x
        (Point3::new(x0, y0 + d, 0.0), V::new(0.0, -d, 0.0), V::new(0.0, 0.0, h)), // -x
        (Point3::new(x0, y0, h), V::new(w, 0.0, 0.0), V::new(0.0, d, 0.0)),   // top
        (Point3::new(x0, y0 + d, 0.0), V::new(w, 0.0, 0.0), V::new(0.0, -d, 0.0)), // bottom
    ];
    for (k, (o, du, dv)) in faces.into_iter().enumerate() {
        let (uv0, uv1) = cell(k as u32);
        b.grid(o, du, dv, uv0, uv1, n);
    }
    b.finish("box", texture::label(1536, 1024, seed ^ 0xB0C5))
}

/// Profile `(radius, z)` of a can from bottom to top.
fn can_profile(r: f32, h: f32) -> Vec<(f32, f32)> {
    let mut p = vec![(r * 0.93, 0.0), (r, 0.004)];
    p.extend((1..12).map(|k| (r, 0.004 + (h - 0.008) * k as f32 / 12.0)));
    p.extend([(r, h - 0.004), (r * 0.93, h)]);
    p
}

/// Profile of a bottle: body, rounded shoulder, neck and cap.
fn bottle_profile() -> Vec<(f32, f32)> {
    let mut p = vec![(0.036, 0.0), (0.04, 0.006)];
    p.extend((1..10).map(|k| (0.04, 0.006 + 0.124 * k as f32 / 10.0)));
    p.extend((0..=8).map(|k| {
        let t = k as f32 / 8.0 * std::f32::consts::FRAC_PI_2;
        (0.016 + 0.024 * t.cos(), 0.13 + 0.038 * t.sin())
    }));
    p.extend([(0.016, 0.182), (0.018, 0.184), (0.018, 0.2)]);
    p
}

/// A closed solid of revolution about z from a `(radius, z)` profile: the side uses the upper
/// 80% of the texture (a label wrapped once around), the lids two discs in the bottom strip.
fn revolved(name: &str, profile: &[(f32, f32)], seed: u64) -> TexturedMesh {
    let mut b = Builder::default();
    let segments = 128u32;
    // Arc length along the profile, for the label's v coordinate.
    let mut arc = vec![0.0f32];
    for w in profile.windows(2) {
        let (d_r, d_z) = (w[1].0 - w[0].0, w[1].1 - w[0].1);
        arc.push(arc.last().unwrap() + (d_r * d_r + d_z * d_z).sqrt());
    }
    let total = *arc.last().unwrap();
    let base = b.positions.len() as u32;
    for (k, &(r, z)) in profile.iter().enumerate() {
        for s in 0..=segments {
            let a = TAU * s as f32 / segments as f32;
            b.vertex(
                Point3::new(r * a.cos(), r * a.sin(), z),
                [s as f32 / segments as f32, 0.2 + 0.8 * arc[k] / total],
            );
        }
    }
    let idx = |k: u32, s: u32| base + k * (segments + 1) + s;
    for k in 0..profile.len() as u32 - 1 {
        for s in 0..segments {
            b.triangles.push([idx(k, s), idx(k, s + 1), idx(k + 1, s + 1)]);
            b.triangles.push([idx(k, s), idx(k + 1, s + 1), idx(k + 1, s)]);
        }
    }
    // Lids: fans around a centre vertex, mapped to discs in the bottom strip of the texture.
    for (top, (r, z)) in [(false, profile[0]), (true, *profile.last().unwrap())] {
        let uc = if top { 0.25 } else { 0.75 };
        let centre = b.vertex(Point3::new(0.0, 0.0, z), [uc, 0.1]);
        let ring: Vec<u32> = (0..=segments)
            .map(|s| {
                let a = TAU * s as f32 / segments as f32;
                b.vertex(Point3::new(r * a.cos(), r * a.sin(), z), [uc + 0.09 * a.cos(), 0.1 + 0.09 * a.sin()])
            })
            .collect();
        for s in 0..segments as usize {
            b.triangles.push(if top { [centre, ring[s], ring[s + 1]] } else { [centre, ring[s + 1], ring[s]] });
        }
    }
    // About 0.3 mm per texel around a 21-25 cm circumference: label print (glyphs of a few
    // millimetres) stays resolvable by a camera seeing 0.6 mm per pixel.
    let mut tex = texture::label(768, 384, seed ^ name.len() as u64 ^ 0xCA7);
    let lid = texture::plain(768, 77, [0.72, 0.72, 0.74], 0.06, seed ^ 0x11D);
    image::imageops::replace(&mut tex, &lid, 0, 384 - 77);
    b.finish(name, tex)
}

/// The turntable: a plain disc of radius `radius` at `z = 0`, finely tessellated so that
/// lens distortion stays exact at the triangle scale.
pub fn turntable_disc(radius: f32, seed: u64) -> TexturedMesh {
    let mut b = Builder::default();
    let (rings, segments) = (12u32, 96u32);
    let centre = b.vertex(Point3::origin(), [0.5, 0.5]);
    let mut prev: Option<Vec<u32>> = None;
    for k in 1..=rings {
        let r = radius * k as f32 / rings as f32;
        let ring: Vec<u32> = (0..=segments)
            .map(|s| {
                let a = TAU * s as f32 / segments as f32;
                let uv = [0.5 + 0.5 * r / radius * a.cos(), 0.5 + 0.5 * r / radius * a.sin()];
                b.vertex(Point3::new(r * a.cos(), r * a.sin(), 0.0), uv)
            })
            .collect();
        for s in 0..segments as usize {
            match &prev {
                None => b.triangles.push([centre, ring[s], ring[s + 1]]),
                Some(p) => {
                    b.triangles.push([p[s], ring[s], ring[s + 1]]);
                    b.triangles.push([p[s], ring[s + 1], p[s + 1]]);
                }
            }
        }
        prev = Some(ring);
    }
    b.finish("turntable", texture::plain(256, 256, [0.55, 0.55, 0.53], 0.03, seed ^ 0x7AB1E))
}
