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
    println!();
    println!("Shading models (--shading NAME[:OPTIONS]):");
    for r in shading_models()? {
        print_entry(r.name, r.description, r.options);
    }
    Ok(())
}
