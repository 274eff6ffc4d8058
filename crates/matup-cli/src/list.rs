//! `matup list`: the registered plugins (and the ONNX models found).

use std::io::Write;

use matup_core::{shading_models, upsamplers, PluginOption};

fn print_entry(
    out: &mut impl Write,
    name: &str,
    description: &str,
    options: &[PluginOption],
) -> std::io::Result<()> {
    writeln!(out, "  {name:<12} {description}")?;
    for o in options {
        writeln!(
            out,
            "  {:<12}   option {}={} : {}",
            "", o.key, o.default, o.help
        )?;
    }
    Ok(())
}

/// Prints the list; a closed pipe (`matup list | head`) just ends it.
pub fn run() -> anyhow::Result<()> {
    match print_list(&mut std::io::stdout().lock()) {
        Err(e)
            if e.downcast_ref::<std::io::Error>()
                .is_some_and(|e| e.kind() == std::io::ErrorKind::BrokenPipe) =>
        {
            Ok(())
        }
        other => other,
    }
}

fn print_list(out: &mut impl Write) -> anyhow::Result<()> {
    writeln!(out, "Upsamplers (--upsampler NAME[:OPTIONS]):")?;
    for r in upsamplers()? {
        print_entry(out, r.name, r.description, r.options)?;
    }
    #[cfg(feature = "onnx")]
    {
        writeln!(out)?;
        writeln!(
            out,
            "Models for onnx:NAME (searched in --models-dir, $MATUP_MODELS, ./models, then those built into matup):"
        )?;
        for (name, source, info) in matup_upsamplers::onnx::available_models() {
            writeln!(
                out,
                "  {name:<20} ×{} {} [{}]\n  {:<20} from {source}",
                info.scale, info.description, info.licence, ""
            )?;
        }
        writeln!(out)?;
        writeln!(
            out,
            "GPU adapters (--device gpu:N or gpu:NAME; auto takes the first hardware one, \
             discrete before integrated, never a software one):"
        )?;
        let adapters = matup_upsamplers::gpu::adapters();
        if adapters.is_empty() {
            writeln!(
                out,
                "  none: this machine offers no Vulkan, Metal or DirectX 12 adapter"
            )?;
        }
        for adapter in adapters {
            writeln!(out, "  {adapter}")?;
        }
        let auto = matup_upsamplers::gpu::auto_adapter();
        let cuda = matup_core::device::cuda_ordinal("auto").ok().flatten();
        let chosen = match (cuda, auto) {
            (Some(n), _) => format!("cuda:{n}"),
            (None, Some(a)) => format!("gpu:{} ({})", a.index, a.name),
            (None, None) => "the CPU".into(),
        };
        writeln!(out, "  --device auto runs the networks on {chosen}")?;
    }
    writeln!(out)?;
    writeln!(out, "Shading models (--shading NAME[:OPTIONS]):")?;
    for r in shading_models()? {
        print_entry(out, r.name, r.description, r.options)?;
    }
    Ok(())
}
