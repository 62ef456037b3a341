//! Training pairs for the learned flow network (`tools/train-flow/`): synthesised turntable
//! pairs with exact flow from `flowfilter_synth::true_flow`, at half resolution (the network's
//! working resolution), cropped around the object, written as NumPy `.npy` arrays:
//! `from.npy`, `to.npy` (`[N, S, S]` u8 grey), `flow.npy` (`[N, 2, S, S]` f32, half-resolution
//! pixels) and `valid.npy` (`[N, S, S]` u8: visible object pixels), plus `pairs.txt`.
//!
//! `cargo run --release -p flowfilter-flow --example flow_dataset -- OUT PAIRS SEED OBJECTS`
//! where OBJECTS is a comma list of procedural names (`box`, `can`, `bottle`: a new texture per
//! pair) and YCB object names (from `../shared/data/ycb`). Frames are rendered without noise;
//! the training script adds colour noise.

use flowfilter_bigbird::{FrameId, SensorId};
use flowfilter_flow::lk::to_gray;
use flowfilter_synth::{Rig, Scene, TexturedMesh, procedural, render_frame, true_flow};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Crop size at half resolution.
const S: usize = 160;

struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn below(&mut self, n: usize) -> usize {
        ((self.next() * n as f64) as usize).min(n - 1)
    }
}

fn npy(path: &Path, dtype: &str, shape: &[usize], bytes: &[u8]) {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let mut header = format!("{{'descr': '{dtype}', 'fortran_order': False, 'shape': ({},), }}", dims.join(", "));
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).expect("create"));
    f.write_all(b"\x93NUMPY\x01\x00").unwrap();
    f.write_all(&(header.len() as u16).to_le_bytes()).unwrap();
    f.write_all(header.as_bytes()).unwrap();
    f.write_all(bytes).unwrap();
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let out = PathBuf::from(&args[1]);
    let pairs: usize = args[2].parse().expect("PAIRS");
    let seed: u64 = args[3].parse().expect("SEED");
    let names: Vec<String> = args[4].split(',').map(str::to_string).collect();
    std::fs::create_dir_all(&out).unwrap();
    let ycb = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/ycb");
    let meshes: Vec<Option<TexturedMesh>> = names
        .iter()
        .map(|n| {
            (!["box", "can", "bottle"].contains(&n.as_str()))
                .then(|| TexturedMesh::load_obj(ycb.join(n).join("textured.obj")).expect("YCB object"))
        })
        .collect();
    let rig = Rig::bigbird_like();
    let mut rng = Lcg(seed ^ 0x5EED_F10E);
    let (mut from_all, mut to_all, mut flow_all, mut valid_all) = (vec![], vec![], vec![], vec![]);
    let mut log = String::new();
    let mut made = 0;
    while made < pairs {
        let o = rng.below(names.len());
        let tex_seed = rng.below(1000) as u64;
        let mesh = match &meshes[o] {
            Some(m) => m.clone(),
            None => procedural(&names[o], tex_seed).expect("procedural"),
        };
        let offset = ((rng.next() - 0.5) * 0.04, (rng.next() - 0.5) * 0.04);
        let scene = Scene::new(mesh.placed_on_table(offset.0 as f32, offset.1 as f32), tex_seed);
        let sensor = SensorId::new(1 + rng.below(5) as u8).unwrap();
        let base = 3 * rng.below(120) as u32;
        let step = 1 + rng.below(20) as u32;
        let to_angle = if rng.next() < 0.5 { (base + step) % 360 } else { (base + 360 - step) % 360 };
        let (a, b) = (FrameId { sensor, angle: base }, FrameId { sensor, angle: to_angle });
        let truth = true_flow(&scene, &rig, a, b, 0.003);
        let (ga, gb) = (
            to_gray(&render_frame(&scene, &rig, sensor, base, None, tex_seed).color),
            to_gray(&render_frame(&scene, &rig, sensor, to_angle, None, tex_seed).color),
        );
        let (w, h) = (ga.width() / 2, ga.height() / 2);
        // Object centre at half resolution, jittered; the crop stays inside the image.
        let (mut cx, mut cy, mut n) = (0.0, 0.0, 0.0);
        for (k, &v) in truth.visible.as_slice().iter().enumerate() {
            if v {
                cx += (k % ga.width()) as f64 / 2.0;
                cy += (k / ga.width()) as f64 / 2.0;
                n += 1.0;
            }
        }
        if n < 2000.0 {
            continue;
        }
        let jitter = |r: &mut Lcg| (r.next() - 0.5) * 60.0;
        let x0 = ((cx / n + jitter(&mut rng)) as isize - S as isize / 2).clamp(0, (w - S) as isize) as usize;
        let y0 = ((cy / n + jitter(&mut rng)) as isize - S as isize / 2).clamp(0, (h - S) as isize) as usize;
        let half = |g: &flowfilter_flow::lk::Gray, x: usize, y: usize| {
            let s = g.at(2 * x, 2 * y) + g.at(2 * x + 1, 2 * y) + g.at(2 * x, 2 * y + 1) + g.at(2 * x + 1, 2 * y + 1);
            (s * 255.0 / 4.0).round().clamp(0.0, 255.0) as u8
        };
        let mut fl = vec![0f32; 2 * S * S];
        for y in 0..S {
            for x in 0..S {
                let (hx, hy) = (x0 + x, y0 + y);
                from_all.push(half(&ga, hx, hy));
                to_all.push(half(&gb, hx, hy));
                let ks = [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(dx, dy)| (2 * hy + dy) * ga.width() + 2 * hx + dx);
                let ok = ks.iter().all(|&k| truth.visible.as_slice()[k]);
                valid_all.push(u8::from(ok));
                if ok {
                    for c in 0..2 {
                        fl[c * S * S + y * S + x] = ks.iter().map(|&k| truth.flow.as_slice()[k][c]).sum::<f32>() / 8.0;
                    }
                }
            }
        }
        flow_all.extend(fl.iter().flat_map(|v| v.to_le_bytes()));
        log.push_str(&format!("{} {} {} {} crop {} {}\n", names[o], tex_seed, a, b, x0, y0));
        made += 1;
        if made % 50 == 0 {
            eprintln!("{made}/{pairs}");
        }
    }
    npy(&out.join("from.npy"), "|u1", &[pairs, S, S], &from_all);
    npy(&out.join("to.npy"), "|u1", &[pairs, S, S], &to_all);
    npy(&out.join("valid.npy"), "|u1", &[pairs, S, S], &valid_all);
    npy(&out.join("flow.npy"), "<f4", &[pairs, 2, S, S], &flow_all);
    std::fs::write(out.join("pairs.txt"), log).unwrap();
}
