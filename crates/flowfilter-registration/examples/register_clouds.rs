//! Register two PLY clouds with every backend and print each estimate against the first.
//! Run: `cargo run --release -p flowfilter-registration --example register_clouds --
//! fixtures/peers/registration/case_3_source.ply fixtures/peers/registration/case_3_target.ply`.

use flowfilter_depth::ply::read_ply;
use flowfilter_registration::{RegistrationConfig, RegistrationProblem, registrar_by_name};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [source, target] = args.as_slice() else { return Err("usage: register_clouds SOURCE.ply TARGET.ply".into()) };
    let problem = RegistrationProblem::new(read_ply(source.as_ref())?, read_ply(target.as_ref())?);
    let config = RegistrationConfig::default();
    for method in ["icp-pt2pt", "icp-pt2pl", "filterreg-pt2pt", "filterreg-pt2pl", "cpd"] {
        let registrar = registrar_by_name(method, &config)?;
        let started = std::time::Instant::now();
        match registrar.register(&problem) {
            Ok(r) => println!(
                "{method:>16}: rotation {:7.3} deg, translation {:6.2} mm, fitness {:.3}, {} iterations, {:.1} ms",
                r.transform.rotation.angle().to_degrees(),
                r.transform.translation.vector.norm() * 1e3,
                r.fitness,
                r.iterations,
                started.elapsed().as_secs_f64() * 1e3
            ),
            Err(e) => println!("{method:>16}: {e}"),
        }
    }
    Ok(())
}
