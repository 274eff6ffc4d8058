//! `matup list`: the registered plugins.

use matup_core::{shading_models, upsamplers, PluginOption};

fn print_entry(name: &str, description: &str, options: &[PluginOption]) {
    println!("  {name:<12} {description}");
    for o in options {
        println!("  {:<12}   option {}={} : {}", "", o.key, o.default, o.help);
    }
}

pub fn run() -> anyhow::Result<()> {
    println!("Upsamplers (--upsampler NAME[:OPTIONS]):");
    for r in upsamplers()? {
        print_entry(r.name, r.description, r.options);
    }
    #[cfg(feature = "onnx")]
    {
        println!();
        println!("Models for onnx:NAME (folders: $MATUP_MODELS, --models-dir, ./models, matup's models/):");
        for (name, path, info) in matup_upsamplers::onnx::available_models() {
            println!(
                "  {name:<20} ×{} {} [{}] {}",
                info.scale,
                info.description,
                info.licence,
                path.display()
            );
        }
    }
    println!();
    println!("Shading models (--shading NAME[:OPTIONS]):");
    for r in shading_models()? {
        print_entry(r.name, r.description, r.options);
    }
    Ok(())
}
