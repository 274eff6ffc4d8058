//! Any Python callable as matup's network: `fn(batch)` takes an N×H×W×3 float32 array in
//! [0, 1] and returns N×sH×sW×3. It is registered for the length of a run as a `callable`
//! upsampler (matup-upsamplers' `function`), so matup tiles, pads, ensembles and
//! back-projects around it exactly as around its own networks.

use std::sync::atomic::{AtomicUsize, Ordering};

use numpy::{PyArray1, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;

use matup::core::{Error, Map};
use matup::upsamplers::function::{register, FunctionTiles, FunctionUpsampler, Registered};

use crate::progress::Raised;
use crate::{interleaved, planar, to_python};

/// Registrations made in this process: each run's name is made unique with the count.
static RUNS: AtomicUsize = AtomicUsize::new(0);

/// A Python callable and how to tile for it.
#[pyclass(frozen, module = "matup._matup")]
pub struct Network {
    function: Py<PyAny>,
    name: String,
    tiles: FunctionTiles,
}

#[pymethods]
impl Network {
    #[new]
    fn new(
        function: Py<PyAny>,
        name: String,
        scale: usize,
        tile: usize,
        overlap: usize,
        batch: usize,
    ) -> Network {
        // The name goes into a spec (`callable:NAME`), where ',' and ':' separate options.
        let name = name.replace([',', ':'], "_");
        Network {
            function,
            name,
            tiles: FunctionTiles {
                scale,
                tile,
                overlap,
                batch,
            },
        }
    }

    #[getter]
    fn scale(&self) -> usize {
        self.tiles.scale
    }

    #[getter]
    fn name(&self) -> &str {
        &self.name
    }

    fn __repr__(&self) -> String {
        let t = self.tiles;
        format!(
            "Network({}, scale={}, tile={}, overlap={}, batch={})",
            self.name, t.scale, t.tile, t.overlap, t.batch
        )
    }
}

impl Network {
    /// Registers the callable for one run; what it raises is kept in `raised`.
    pub fn register(&self, py: Python<'_>, raised: &Raised) -> PyResult<Registered> {
        let function = self.function.clone_ref(py);
        let raised = raised.clone();
        let name = format!("{}#{}", self.name, RUNS.fetch_add(1, Ordering::Relaxed));
        let plugin = format!("callable:{name}");
        let run = move |tiles: &[Vec<f32>], [h, w]: [usize; 2]| -> matup::core::Result<Vec<Map>> {
            Python::attach(|py| {
                // Ctrl-C between calls; then the call, whose exception is kept.
                let outcome = py
                    .check_signals()
                    .and_then(|()| call(py, &function, tiles, [h, w]));
                outcome.unwrap_or_else(|e| {
                    raised.keep(e);
                    Err(Error::Plugin {
                        plugin: plugin.clone(),
                        message: "the callable raised an exception".into(),
                    })
                })
            })
        };
        let upsampler = FunctionUpsampler::new(name, self.tiles, Box::new(run))
            .map_err(|e| to_python(py, &e))?;
        register(upsampler).map_err(|e| to_python(py, &e))
    }
}

/// One call of the callable: the tiles as an N×H×W×3 array, its output back as maps. A
/// Python exception is the outer error; an output of the wrong form, the inner.
fn call(
    py: Python<'_>,
    function: &Py<PyAny>,
    tiles: &[Vec<f32>],
    [h, w]: [usize; 2],
) -> PyResult<matup::core::Result<Vec<Map>>> {
    let n = tiles.len();
    let batch: Vec<f32> = tiles.iter().flat_map(|tile| interleaved(tile, 3)).collect();
    let input = PyArray1::from_vec(py, batch).reshape([n, h, w, 3])?;
    let output = function.call1(py, (input,))?;
    // Whatever array-like it returns (a NumPy array, a CPU tensor), as float32 texels.
    let numpy = py.import("numpy")?;
    let output = numpy.call_method1("ascontiguousarray", (output, "float32"))?;
    let array: PyReadonlyArrayDyn<f32> = output.extract()?;
    let shape = array.shape().to_vec();
    let [count, oh, ow, 3] = shape[..] else {
        return Ok(Err(Error::Invalid(format!(
            "the callable returned shape {shape:?} for a batch of {:?}: want (N, H·s, W·s, 3)",
            [n, h, w, 3]
        ))));
    };
    if oh == 0 || ow == 0 {
        return Ok(Err(Error::Invalid(format!(
            "the callable returned shape {shape:?}, which holds no texels"
        ))));
    }
    if count != n {
        return Ok(Err(Error::Invalid(format!(
            "the callable returned {count} images for a batch of {n}"
        ))));
    }
    let values = array.as_slice()?;
    if values.iter().any(|v| !v.is_finite()) {
        return Ok(Err(Error::Invalid(
            "the callable returned NaN or infinity".into(),
        )));
    }
    Ok(Ok((values.chunks_exact(oh * ow * 3))
        .map(|image| Map::from_planar(ow, oh, 3, planar(image, 3)))
        .collect()))
}

/// A run's Python networks, registered for its length: its upsampler, and matup's own networks
/// run through others (`networks`: by model name, as `Config::networks` takes them).
#[derive(Default)]
pub struct RunNetworks {
    pub upsampler: Option<Registered>,
    pub instead: Vec<(String, Registered)>,
}

impl RunNetworks {
    pub fn register(
        py: Python<'_>,
        upsampler: Option<&Network>,
        networks: Vec<(String, PyRef<'_, Network>)>,
        raised: &Raised,
    ) -> PyResult<RunNetworks> {
        let upsampler = upsampler.map(|n| n.register(py, raised)).transpose()?;
        let instead = (networks.into_iter())
            .map(|(name, n)| Ok((name, n.register(py, raised)?)))
            .collect::<PyResult<_>>()?;
        Ok(RunNetworks { upsampler, instead })
    }
}
