//! Textured triangle meshes: OBJ + MTL + texture loading, validation, vertex normals.

use crate::error::SynthError;
use image::RgbImage;
use nalgebra::{Point3, Vector3};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// A textured triangle mesh in metres, one index per vertex (positions, UVs and normals share
/// indices; seams are duplicated vertices).
#[derive(Debug, Clone)]
pub struct TexturedMesh {
    /// Where the mesh came from (a file, or `procedural:<name>`), for error messages.
    pub source: PathBuf,
    /// Vertex positions.
    pub positions: Vec<Point3<f32>>,
    /// Texture coordinates, OBJ convention (`v = 0` at the bottom row of the image).
    pub uvs: Vec<[f32; 2]>,
    /// Unit vertex normals.
    pub normals: Vec<Vector3<f32>>,
    /// Triangles as vertex indices.
    pub triangles: Vec<[u32; 3]>,
    /// The diffuse texture.
    pub texture: Arc<RgbImage>,
    /// Mip levels of the texture (level 0 = the texture; each next level halves both sides by
    /// 2x2 box filtering), for sampling minified textures without aliasing.
    pub mips: Arc<Vec<RgbImage>>,
}

/// Box-filtered mip chain of an image, down to 1x1.
fn mip_chain(img: &RgbImage) -> Vec<RgbImage> {
    let mut levels = vec![img.clone()];
    while let Some(last) = levels.last() {
        if last.width() <= 1 && last.height() <= 1 {
            break;
        }
        let (w, h) = ((last.width() / 2).max(1), (last.height() / 2).max(1));
        let next = RgbImage::from_fn(w, h, |x, y| {
            let mut acc = [0u32; 3];
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let p = last.get_pixel((2 * x + dx).min(last.width() - 1), (2 * y + dy).min(last.height() - 1)).0;
                for c in 0..3 {
                    acc[c] += u32::from(p[c]);
                }
            }
            image::Rgb(acc.map(|v| ((v + 2) / 4) as u8))
        });
        levels.push(next);
    }
    levels
}

impl TexturedMesh {
    /// Build a mesh, computing area-weighted vertex normals and validating it: at least one
    /// triangle of positive area, finite coordinates, indices in range, a non-empty texture.
    pub fn new(
        source: PathBuf,
        positions: Vec<Point3<f32>>,
        uvs: Vec<[f32; 2]>,
        triangles: Vec<[u32; 3]>,
        texture: Arc<RgbImage>,
    ) -> Result<Self, SynthError> {
        let degenerate = |message: String| SynthError::DegenerateMesh { path: source.clone(), message };
        if positions.iter().any(|p| !p.coords.iter().all(|c| c.is_finite())) {
            return Err(degenerate("a vertex has a non-finite coordinate".into()));
        }
        if uvs.len() != positions.len() {
            return Err(degenerate(format!("{} texture coordinates for {} vertices", uvs.len(), positions.len())));
        }
        if let Some(t) = triangles.iter().find(|t| t.iter().any(|&i| i as usize >= positions.len())) {
            return Err(degenerate(format!("triangle {t:?} indexes past the {} vertices", positions.len())));
        }
        if texture.width() == 0 || texture.height() == 0 {
            return Err(SynthError::Texture { path: source, message: "texture image is empty".into() });
        }
        let mut normals = vec![Vector3::<f32>::zeros(); positions.len()];
        let mut area = 0.0f64;
        for t in &triangles {
            let [a, b, c] = t.map(|i| positions[i as usize]);
            let n = (b - a).cross(&(c - a)); // length = 2 * area: area weighting
            area += 0.5 * f64::from(n.norm());
            for &i in t {
                normals[i as usize] += n;
            }
        }
        if triangles.is_empty() || area < 1e-10 {
            return Err(degenerate(format!("{} triangles with total area {area:.3e} m^2", triangles.len())));
        }
        for n in &mut normals {
            *n = n.try_normalize(1e-20).unwrap_or_else(Vector3::z);
        }
        let mips = Arc::new(mip_chain(&texture));
        Ok(Self { source, positions, uvs, normals, triangles, texture, mips })
    }

    /// Load an OBJ with its MTL's diffuse texture (`map_Kd`). All meshes in the file are merged;
    /// every face must be a triangle and every vertex must have texture coordinates.
    pub fn load_obj(path: impl AsRef<Path>) -> Result<Self, SynthError> {
        let path = path.as_ref();
        let obj_err = |message: String| SynthError::Obj { path: path.into(), message };
        if !path.is_file() {
            return Err(obj_err("file not found".into()));
        }
        let opts = tobj::LoadOptions { single_index: true, triangulate: false, ..Default::default() };
        let (models, materials) = tobj::load_obj(path, &opts).map_err(|e| obj_err(e.to_string()))?;
        if models.is_empty() {
            return Err(SynthError::DegenerateMesh { path: path.into(), message: "no mesh in the file".into() });
        }
        let materials = materials
            .map_err(|e| SynthError::Texture { path: path.into(), message: format!("cannot read its MTL: {e}") })?;
        let dir = path.parent().unwrap_or(Path::new("."));
        let texture_name = models
            .iter()
            .filter_map(|m| m.mesh.material_id)
            .filter_map(|id| materials.get(id))
            .find_map(|m| m.diffuse_texture.clone())
            .ok_or_else(|| SynthError::Texture {
                path: path.into(),
                message: "no material with a diffuse texture (map_Kd) is used by the mesh".into(),
            })?;
        let texture_path = dir.join(texture_name.trim());
        if !texture_path.is_file() {
            return Err(SynthError::Texture { path: texture_path, message: "texture image not found".into() });
        }
        let texture = image::open(&texture_path)
            .map_err(|e| SynthError::Texture { path: texture_path.clone(), message: format!("cannot decode: {e}") })?
            .to_rgb8();

        let (mut positions, mut uvs, mut triangles) = (Vec::new(), Vec::new(), Vec::new());
        for model in &models {
            let m = &model.mesh;
            if let Some((face, &arity)) = m.face_arities.iter().enumerate().find(|(_, a)| **a != 3) {
                return Err(SynthError::NotTriangulated { path: path.into(), mesh: model.name.clone(), face, arity });
            }
            let n = m.positions.len() / 3;
            if m.texcoords.len() != 2 * n {
                return Err(SynthError::Texture {
                    path: path.into(),
                    message: format!("mesh '{}' has no texture coordinates (vt) for its vertices", model.name),
                });
            }
            let base = positions.len() as u32;
            positions.extend(m.positions.chunks_exact(3).map(|p| Point3::new(p[0], p[1], p[2])));
            uvs.extend(m.texcoords.chunks_exact(2).map(|t| [t[0], t[1]]));
            triangles.extend(m.indices.chunks_exact(3).map(|t| [base + t[0], base + t[1], base + t[2]]));
        }
        Self::new(path.into(), positions, uvs, triangles, Arc::new(texture))
    }

    /// Axis-aligned bounds `(min, max)`.
    pub fn bounds(&self) -> (Point3<f32>, Point3<f32>) {
        let mut lo = Point3::new(f32::INFINITY, f32::INFINITY, f32::INFINITY);
        let mut hi = Point3::new(f32::NEG_INFINITY, f32::NEG_INFINITY, f32::NEG_INFINITY);
        for p in &self.positions {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        (lo, hi)
    }

    /// Translate so that the bounding box's centre is the origin: the object frame of the
    /// YCB-Video annotations (its models are the YCB scans moved so), where the scans themselves
    /// put the origin elsewhere.
    pub fn centred(mut self) -> Self {
        let (lo, hi) = self.bounds();
        let shift = -(lo.coords + hi.coords) / 2.0;
        for p in &mut self.positions {
            *p += shift;
        }
        self
    }

    /// Translate so that the bounding box is centred on the z axis and rests on `z = 0`
    /// (how an object stands on the turntable), plus an extra `(dx, dy)` offset.
    pub fn placed_on_table(mut self, dx: f32, dy: f32) -> Self {
        let (lo, hi) = self.bounds();
        let shift = Vector3::new(-(lo.x + hi.x) / 2.0 + dx, -(lo.y + hi.y) / 2.0 + dy, -lo.z);
        for p in &mut self.positions {
            *p += shift;
        }
        self
    }

    /// Bilinear texture lookup at OBJ texture coordinates (wrapping), as linear RGB in [0, 1].
    pub fn sample_texture(&self, uv: [f32; 2]) -> [f32; 3] {
        Self::bilinear(&self.texture, uv)
    }

    /// Trilinear (mip-mapped) lookup for a pixel whose footprint spans `texels` texels of the
    /// full-resolution texture: what a camera pixel integrating over its area sees.
    pub fn sample_texture_footprint(&self, uv: [f32; 2], texels: f32) -> [f32; 3] {
        let lod = texels.max(1.0).log2().min((self.mips.len() - 1) as f32);
        let (l0, f) = (lod.floor() as usize, lod - lod.floor());
        let a = Self::bilinear(&self.mips[l0], uv);
        if f <= 0.0 || l0 + 1 >= self.mips.len() {
            return a;
        }
        let b = Self::bilinear(&self.mips[l0 + 1], uv);
        std::array::from_fn(|k| a[k] * (1.0 - f) + b[k] * f)
    }

    fn bilinear(t: &RgbImage, uv: [f32; 2]) -> [f32; 3] {
        let (w, h) = (t.width() as f32, t.height() as f32);
        let x = uv[0].rem_euclid(1.0) * w - 0.5;
        let y = (1.0 - uv[1].rem_euclid(1.0)) * h - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let wrap = |v: f32, n: u32| (v as i64).rem_euclid(i64::from(n)) as u32;
        let (xa, xb) = (wrap(x0, t.width()), wrap(x0 + 1.0, t.width()));
        let (ya, yb) = (wrap(y0, t.height()), wrap(y0 + 1.0, t.height()));
        let px = |x: u32, y: u32| t.get_pixel(x, y).0;
        let (a, b, c, d) = (px(xa, ya), px(xb, ya), px(xa, yb), px(xb, yb));
        std::array::from_fn(|k| {
            let top = f32::from(a[k]) * (1.0 - fx) + f32::from(b[k]) * fx;
            let bottom = f32::from(c[k]) * (1.0 - fx) + f32::from(d[k]) * fx;
            (top * (1.0 - fy) + bottom * fy) / 255.0
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn large_footprints_average_the_texture() {
        // A one-texel checkerboard: sampled with a 16-texel footprint it is its mean, grey.
        let tex = RgbImage::from_fn(64, 64, |x, y| {
            if (x + y) % 2 == 0 { image::Rgb([255, 255, 255]) } else { image::Rgb([0, 0, 0]) }
        });
        let mesh = TexturedMesh::new(
            PathBuf::from("test"),
            vec![Point3::origin(), Point3::new(1.0, 0.0, 0.0), Point3::new(0.0, 1.0, 0.0)],
            vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
            vec![[0, 1, 2]],
            Arc::new(tex),
        )
        .unwrap();
        assert_eq!(mesh.mips.len(), 7);
        let c = mesh.sample_texture_footprint([0.3, 0.6], 16.0);
        assert!(c.iter().all(|v| (v - 0.5).abs() < 0.01), "{c:?}");
        // A one-texel footprint keeps the full-resolution texture.
        let sharp = mesh.sample_texture_footprint([0.5 / 64.0, 1.0 - 0.5 / 64.0], 1.0);
        assert!(sharp.iter().all(|v| *v > 0.99 || *v < 0.01), "{sharp:?}");
    }
}
