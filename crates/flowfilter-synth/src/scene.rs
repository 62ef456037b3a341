//! A turntable scene: the object and the table disc in the table frame, and the lighting.

use crate::mesh::TexturedMesh;
use crate::procedural::turntable_disc;
use nalgebra::{Point3, Vector3};

/// Radius of the turntable disc, metres.
pub const TABLE_RADIUS: f32 = 0.22;

/// The object standing on the turntable disc, both in the table frame (z up, origin at the
/// turntable centre on its surface), lit by a fixed directional light plus ambient light.
#[derive(Debug, Clone)]
pub struct Scene {
    /// The object.
    pub object: TexturedMesh,
    /// The turntable disc.
    pub table: TexturedMesh,
    /// Direction towards the light, in the world frame (unit).
    pub light_world: Vector3<f32>,
    /// Ambient term.
    pub ambient: f32,
    /// Lambertian term.
    pub diffuse: f32,
    /// Colour where no surface is hit.
    pub background: [u8; 3],
    /// Object and table vertices, object first.
    pub(crate) positions: Vec<Point3<f32>>,
    /// Object and table triangles, object first (table indices offset).
    pub(crate) triangles: Vec<[u32; 3]>,
}

impl Scene {
    /// Put an object (already standing on `z = 0`) on the turntable disc.
    pub fn new(object: TexturedMesh, seed: u64) -> Self {
        let table = turntable_disc(TABLE_RADIUS, seed);
        let offset = object.positions.len() as u32;
        let positions = object.positions.iter().chain(&table.positions).copied().collect();
        let triangles =
            object.triangles.iter().copied().chain(table.triangles.iter().map(|t| t.map(|i| i + offset))).collect();
        Self::lit(object, table, positions, triangles)
    }

    /// The object alone, without the table: [`Scene::new`] then [`Scene::object_only`], without
    /// building and copying what is then dropped.
    pub(crate) fn alone(object: TexturedMesh, seed: u64) -> Self {
        let (positions, triangles) = (object.positions.clone(), object.triangles.clone());
        Self::lit(object, turntable_disc(TABLE_RADIUS, seed), positions, triangles)
    }

    /// A scene of these meshes and render lists under the fixed light.
    fn lit(object: TexturedMesh, table: TexturedMesh, positions: Vec<Point3<f32>>, triangles: Vec<[u32; 3]>) -> Self {
        Self {
            object,
            table,
            light_world: Vector3::new(0.35, -0.55, 0.76).normalize(),
            ambient: 0.4,
            diffuse: 0.65,
            background: [38, 38, 42],
            positions,
            triangles,
        }
    }

    /// Number of object triangles (scene triangles below this index are the object's).
    pub fn object_triangles(&self) -> usize {
        self.object.triangles.len()
    }

    /// The object alone, without the table (for its unoccluded silhouette).
    pub(crate) fn object_only(&self) -> Self {
        let mut only = self.clone();
        only.positions.truncate(self.object.positions.len());
        only.triangles.truncate(self.object.triangles.len());
        only
    }

    /// The mesh and local triangle index of a scene triangle.
    pub(crate) fn locate(&self, t: u32) -> (&TexturedMesh, usize) {
        let n = self.object.triangles.len();
        if (t as usize) < n { (&self.object, t as usize) } else { (&self.table, t as usize - n) }
    }
}
