//! Bad meshes and options give clear, typed errors.

use flowfilter_synth::{SynthError, TexturedMesh, procedural};
use std::path::Path;

fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn texture(dir: &Path) {
    image::RgbImage::from_pixel(4, 4, image::Rgb([200, 10, 10])).save(dir.join("tex.png")).unwrap();
}

const MTL: &str = "newmtl m\nmap_Kd tex.png\n";

#[test]
fn unreadable_obj() {
    let e = TexturedMesh::load_obj("/no/such/mesh.obj").unwrap_err();
    assert!(matches!(e, SynthError::Obj { .. }) && e.to_string().contains("/no/such/mesh.obj"), "{e}");
    let tmp = tempfile::tempdir().unwrap();
    let p = write(tmp.path(), "bad.obj", "v 0 0 zero\nf 1 2 3\n");
    let e = TexturedMesh::load_obj(&p).unwrap_err();
    assert!(e.to_string().contains("bad.obj"), "{e}");
}

#[test]
fn quads_are_not_triangulated() {
    let tmp = tempfile::tempdir().unwrap();
    texture(tmp.path());
    write(tmp.path(), "m.mtl", MTL);
    let p = write(
        tmp.path(),
        "quad.obj",
        "mtllib m.mtl\nusemtl m\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n",
    );
    let e = TexturedMesh::load_obj(&p).unwrap_err();
    assert!(matches!(e, SynthError::NotTriangulated { arity: 4, .. }), "{e}");
    assert!(e.to_string().contains("not triangulated"), "{e}");
}

#[test]
fn missing_texture_and_missing_uvs() {
    let tmp = tempfile::tempdir().unwrap();
    write(tmp.path(), "m.mtl", MTL);
    let tri = "mtllib m.mtl\nusemtl m\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n";
    let p = write(tmp.path(), "t.obj", tri);
    let e = TexturedMesh::load_obj(&p).unwrap_err();
    assert!(matches!(&e, SynthError::Texture { path, .. } if path.ends_with("tex.png")), "{e}");
    assert!(e.to_string().contains("texture image not found"), "{e}");

    texture(tmp.path());
    let p = write(tmp.path(), "nouv.obj", "mtllib m.mtl\nusemtl m\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let e = TexturedMesh::load_obj(&p).unwrap_err();
    assert!(e.to_string().contains("no texture coordinates"), "{e}");

    let p = write(tmp.path(), "nomtl.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n");
    let e = TexturedMesh::load_obj(&p).unwrap_err();
    assert!(e.to_string().contains("map_Kd"), "{e}");
}

#[test]
fn degenerate_mesh() {
    let tmp = tempfile::tempdir().unwrap();
    texture(tmp.path());
    write(tmp.path(), "m.mtl", MTL);
    let p = write(
        tmp.path(),
        "flat.obj",
        "mtllib m.mtl\nusemtl m\nv 0 0 0\nv 0 0 0\nv 0 0 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n",
    );
    let e = TexturedMesh::load_obj(&p).unwrap_err();
    assert!(matches!(e, SynthError::DegenerateMesh { .. }), "{e}");
    assert!(e.to_string().contains("degenerate mesh"), "{e}");
    let e = procedural("teapot", 0).unwrap_err();
    assert!(e.to_string().contains("box, can, bottle"), "{e}");
}
