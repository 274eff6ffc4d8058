//! The two training backends compute the same thing: the tensor backend (candle operations
//! and autograd, any device; here the CPU) against the fused CPU kernels, on the shipped
//! sample.

mod common;

use matup::config::{Backend, Config};
use matup::material::Material;
use matup::progress::{Progress, Silent};
use matup::{RunOptions, RunReport};

fn sample() -> Material {
    matup::load_material(Some(&common::sample_material()), &Default::default()).unwrap()
}

/// The paper's settings with `lanczos3` targets, 3 epochs of 16 384 texels (128 steps each).
fn config(backend: Backend) -> Config {
    let mut c = Config {
        upsampler: "lanczos3".into(),
        seed: 3,
        ..Config::paper()
    };
    c.train.epochs = 3;
    c.train.texels_per_epoch = Some(16_384);
    c.train.backend = backend;
    c
}

fn run(config: &Config, options: &RunOptions, progress: &dyn Progress) -> (Material, RunReport) {
    matup::upscale(&sample(), config, options, progress).unwrap()
}

#[test]
fn the_tensor_backend_trains_to_the_fused_loss() {
    let (fused, fused_report) = run(&config(Backend::Fused), &RunOptions::default(), &Silent);
    let (tensor, tensor_report) = run(&config(Backend::Tensor), &RunOptions::default(), &Silent);
    let (a, b) = (
        &fused_report.levels[0].training,
        &tensor_report.levels[0].training,
    );
    assert_eq!(
        (a.backend.as_str(), b.backend.as_str()),
        ("fused", "tensor")
    );
    assert_eq!(a.steps, b.steps);
    // Same start, same batches: the losses agree to the last epoch, as far as sums taken in
    // different orders let them (candle picks its matrix kernels by CPU: 1.3·10⁻³ apart on an
    // AVX-512 EPYC, 0.0187024 against 0.0187272).
    let (x, y) = (a.epoch_losses[2], b.epoch_losses[2]);
    assert!(((x - y) / x).abs() <= 3e-3, "fused {x}, tensor {y}");
    assert!(
        y < b.epoch_losses[0],
        "the tensor backend trains: {:?}",
        b.epoch_losses
    );
    // And so do the maps they give (base colour, 8-bit steps are 0.004).
    let diff = fused
        .base_color
        .data()
        .iter()
        .zip(tensor.base_color.data())
        .map(|(p, q)| (p - q).abs() as f64)
        .sum::<f64>()
        / fused.base_color.data().len() as f64;
    assert!(diff < 1e-3, "mean base colour difference {diff}");
}

#[test]
fn an_interrupted_tensor_run_resumes_from_its_checkpoint() {
    let c = config(Backend::Tensor);
    let folder = tempfile::tempdir().unwrap();
    // 128 steps an epoch: stop during the second.
    let options = common::interrupt_in_second_epoch(&sample(), &c, folder.path(), 128 + 40);
    let (_, resumed) = run(&c, &options, &Silent);
    let (_, whole) = run(&c, &RunOptions::default(), &Silent);
    let (r, w) = (&resumed.levels[0].training, &whole.levels[0].training);
    assert_eq!(r.resumed_epochs, 1);
    assert_eq!(
        r.epoch_losses[0], w.epoch_losses[0],
        "the first epoch comes from the checkpoint"
    );
    // The weights and Adam's moments resume exactly: the rest is the uninterrupted run's.
    assert_eq!(r.epoch_losses, w.epoch_losses);
}

#[test]
fn backends_and_devices_are_checked_before_anything_runs() {
    let mut c = config(Backend::Tensor);
    c.train.lr_consistency = 10.0;
    let e = c.validate().unwrap_err().to_string();
    assert!(e.contains("fused backend only"), "{e}");

    let mut c = config(Backend::Fused);
    c.device = "cuda".into();
    let e = c.validate().unwrap_err().to_string();
    assert!(e.contains("CPU only"), "{e}");

    let mut c = config(Backend::Auto);
    c.device = "tpu".into();
    let e = c.validate().unwrap_err().to_string();
    assert!(
        e.contains("use auto, cpu, gpu, gpu:N, gpu:NAME, cuda or cuda:N"),
        "{e}"
    );
    // A wgpu adapter runs the networks; the filter then trains on the CPU.
    let mut c = config(Backend::Fused);
    c.device = "gpu:llvmpipe".into();
    c.validate().unwrap();

    // This build has no CUDA: asking for it says so instead of failing later, also where
    // nothing would be trained (the defaults) and the request would otherwise pass unused.
    if !matup::candle_core::utils::cuda_is_available() {
        let mut c = config(Backend::Auto);
        c.device = "cuda:0".into();
        let error = matup::upscale(&sample(), &c, &RunOptions::default(), &Silent).unwrap_err();
        assert!(error.to_string().contains("--features cuda"), "{error}");
        let defaults = Config {
            device: "cuda".into(),
            ..Config::default()
        };
        let error = defaults.validate().unwrap_err().to_string();
        assert!(error.contains("--features cuda"), "{error}");
    }
}
