//! Print the default pipeline configuration as TOML:
//! `cargo run -p flowfilter-pipeline --example default_config`.

fn main() {
    print!("{}", flowfilter_pipeline::PipelineConfig::default().to_toml());
}
