//! Texel·light evaluations per second of `ggx` at 512² × 100 lights: forward (render) and
//! forward + backward (the fused render + loss + gradient that training runs).
//!
//! `cargo bench --bench render`

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use matup::render::texels;
use matup::{shading_model, LightSetSpec, LossNorm, Material, PluginSpec, Svbrdf};
use rayon::prelude::*;

fn material(size: usize) -> Material {
    // A material with variation in every parameter, so no branch is always taken.
    let mut m = Material::uniform(size, [0.5; 3], 0.5, 0.0);
    let wave = |i: usize, f: f32| 0.5 + 0.4 * ((i as f32) * f).sin();
    for i in 0..size * size {
        for c in 0..3 {
            m.base_color.plane_mut(c)[i] = wave(i, 0.013 + c as f32 * 0.007);
        }
        m.roughness.data_mut()[i] = wave(i, 0.021);
        m.metallic.data_mut()[i] = wave(i, 0.005);
        let (nx, ny) = (0.3 * (wave(i, 0.017) - 0.5), 0.3 * (wave(i, 0.011) - 0.5));
        let nz = (1.0 - nx * nx - ny * ny).sqrt();
        m.normal.plane_mut(0)[i] = nx;
        m.normal.plane_mut(1)[i] = ny;
        m.normal.plane_mut(2)[i] = nz;
    }
    m
}

fn bench(c: &mut Criterion) {
    let size = 512;
    let model = shading_model(&PluginSpec::new("ggx")).unwrap();
    let lights = LightSetSpec::default().build();
    let texels = texels(&material(size));
    let targets = vec![[0.5f32; 3]; lights.len()];

    let mut group = c.benchmark_group("ggx 512² × 100 lights");
    group.sample_size(10);
    group.throughput(Throughput::Elements((texels.len() * lights.len()) as u64));
    group.bench_function("forward", |b| {
        b.iter(|| {
            texels
                .par_chunks(512)
                .map(|chunk| {
                    let mut out = vec![[0f32; 3]; lights.len()];
                    let mut sum = 0.0;
                    for t in chunk {
                        model.render_texel(t, &lights, &mut out);
                        sum += out[0][0];
                    }
                    sum
                })
                .sum::<f32>()
        })
    });
    group.bench_function("forward+backward (fused loss)", |b| {
        b.iter(|| {
            texels
                .par_chunks(512)
                .map(|chunk| {
                    let mut sum = 0.0;
                    for t in chunk {
                        let mut grad = Svbrdf::default();
                        sum +=
                            model.texel_loss(t, &lights, &targets, &LossNorm::L21, Some(&mut grad));
                        sum += grad.alpha;
                    }
                    sum
                })
                .sum::<f32>()
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
