//! The Neural-Q guide: its network's GPU passes against the CPU reference of
//! `guide::mlp` (whose gradient is itself checked by finite differences), and
//! neural renders against pt (unbiasedness).

mod common;

use common::Lcg;
use glam::Vec3;
use qtrace::guide::mlp::{Adam, MlpShape};
use qtrace::guide::network::Network;
use qtrace::guide::neural::{
    encode, fitted_steps, scene_vertices, Encoding, Inference, Target, Training,
};
use qtrace::guide::{
    Common, DeviceGuide, Distribution, GuideSettings, NeuralGuide, NeuralSettings,
};
use qtrace::render::{probe, Method, Overrides};
use qtrace::sampling;
use qtrace::shaders::MlpTarget;

const SHAPE: MlpShape = MlpShape {
    inputs: 12,
    width: 16,
    hidden: 3,
    outputs: 20,
};

/// Initial parameters with non-zero hidden biases, so that which units are
/// active varies from input to input.
fn params(rng: &mut Lcg) -> Vec<f32> {
    let mut p = SHAPE.init(17, 0.3);
    for layer in &SHAPE.layers() {
        for o in 0..layer.fan_out {
            p[layer.bias(o)] += 0.2 * (rng.next() - 0.5);
        }
    }
    p
}

fn inputs(rng: &mut Lcg, rows: usize) -> Vec<f32> {
    (0..rows * SHAPE.inputs as usize)
        .map(|_| rng.next() * 2.0 - 1.0)
        .collect()
}

fn batch(rng: &mut Lcg, rows: usize) -> (Vec<f32>, Vec<MlpTarget>) {
    let targets = (0..rows)
        .map(|_| MlpTarget {
            sector: rng.below(SHAPE.outputs),
            target: 3.0 * rng.next(),
            ..Default::default()
        })
        .collect();
    (inputs(rng, rows), targets)
}

fn assert_close(what: &str, gpu: &[f32], cpu: &[f32], tol: f32) {
    assert_eq!(gpu.len(), cpu.len(), "{what}: lengths");
    for (i, (g, c)) in gpu.iter().zip(cpu).enumerate() {
        assert!(
            (g - c).abs() <= tol * c.abs().max(1.0),
            "{what}[{i}]: GPU {g} vs CPU {c}"
        );
    }
}

#[test]
fn gpu_inference_matches_cpu() {
    let ctx = common::gpu();
    let mut rng = Lcg(3);
    let p = params(&mut rng);
    let net = Network::new(&ctx, SHAPE, Adam::default(), 16, &p, false).unwrap();
    let rows = 300;
    let x = inputs(&mut rng, rows);
    let gpu = net.infer(&ctx, &x).unwrap();
    common::assert_no_validation_errors(&ctx);
    let cpu: Vec<f32> = x
        .chunks(SHAPE.inputs as usize)
        .flat_map(|row| SHAPE.forward(&p, row))
        .collect();
    assert_close("Q", &gpu, &cpu, 1e-5);
    // Not a constant function: the check means something.
    let spread = cpu.iter().fold(0.0f32, |m, &q| m.max((q - cpu[0]).abs()));
    assert!(spread > 0.05, "Q spread {spread}");
}

#[test]
fn gpu_training_step_matches_cpu() {
    let ctx = common::gpu();
    let mut rng = Lcg(5);
    let mut cpu_params = params(&mut rng);
    let adam = Adam {
        learning_rate: 1e-2,
        ..Adam::default()
    };
    let capacity = 2048;
    let mut net = Network::new(&ctx, SHAPE, adam, capacity, &cpu_params, false).unwrap();
    let n = cpu_params.len();
    let (mut m, mut v) = (vec![0.0; n], vec![0.0; n]);
    // Two steps with different batch sizes: the second checks the moments too.
    // The first batch spans two of the output pass's chunks.
    for (step, rows) in [(1u32, 1500usize), (2, 200)] {
        let (x, targets) = batch(&mut rng, rows);
        net.upload_batch(&x, &targets).unwrap();
        ctx.submit(None, |rec| net.record_training(rec, 1)).unwrap();
        common::assert_no_validation_errors(&ctx);

        let mut grad = vec![0.0; n];
        let mut losses = Vec::new();
        for (row, t) in x.chunks(SHAPE.inputs as usize).zip(&targets) {
            losses.push(SHAPE.gradient(&cpu_params, row, t.sector as usize, t.target, &mut grad));
        }
        grad.iter_mut().for_each(|g| *g /= rows as f32);
        let step_state = Moments {
            m: &mut m,
            v: &mut v,
            step,
        };
        let gpu_params = assert_step_matches(
            &net,
            &format!("step {step}"),
            &losses,
            &grad,
            &mut cpu_params,
            step_state,
        );
        // Keep the two sides on the same parameters.
        cpu_params = gpu_params;
    }
}

/// Adam's moments and step number on the CPU side.
struct Moments<'a> {
    m: &'a mut [f32],
    v: &'a mut [f32],
    step: u32,
}

/// Checks the step the network just took against the CPU twin's: the
/// rows' losses, the mean gradient, and Adam's update of `cpu_params`
/// (which it applies); returns the GPU's parameters.
fn assert_step_matches(
    net: &Network,
    what: &str,
    losses: &[f32],
    grad: &[f32],
    cpu_params: &mut [f32],
    moments: Moments<'_>,
) -> Vec<f32> {
    let n = grad.len();
    let written = net.download_targets().unwrap();
    let gpu_losses: Vec<f32> = written[..losses.len()].iter().map(|t| t.loss).collect();
    assert_close(&format!("{what} loss"), &gpu_losses, losses, 1e-4);

    let gpu_grad = net.download_grad().unwrap();
    let scale = grad.iter().fold(0.0f32, |s, g| s.max(g.abs()));
    assert!(scale > 1e-3, "gradient vanishes: {scale}");
    for (i, (g, c)) in gpu_grad.iter().zip(grad).enumerate() {
        assert!(
            (g - c).abs() <= 1e-4 * scale,
            "{what} gradient[{i}]: GPU {g} vs CPU {c} (largest {scale})"
        );
    }
    let nonzero = grad.iter().filter(|g| g.abs() > 1e-3 * scale).count();
    assert!(nonzero > n / 2, "only {nonzero} of {n} parameters learn");

    net.adam
        .step(cpu_params, moments.m, moments.v, grad, moments.step);
    let gpu_params = net.download_params().unwrap();
    for (i, (g, c)) in gpu_params.iter().zip(cpu_params.iter()).enumerate() {
        // Adam moves each parameter by about the learning rate whatever
        // its gradient's size, so a gradient that is rounding noise on
        // one side may move it the other way: allow that only there.
        let tol = if grad[i].abs() > 1e-3 * scale {
            1e-5
        } else {
            2.0 * net.adam.learning_rate
        };
        assert!(
            (g - c).abs() <= tol,
            "{what} parameter {i}: GPU {g} vs CPU {c}"
        );
    }
    gpu_params
}

/// Settings small enough for the suite: a narrow network, a small batch.
fn small() -> NeuralSettings {
    NeuralSettings {
        width: 16,
        batch: Some(1024),
        ..Default::default()
    }
}

/// The neural render converges to the pt reference: no bias from learning,
/// the mixture pdf or the guided roulette.
fn unbiased(scene_name: &str, nee: bool, spp: u32, settings: NeuralSettings) {
    let scene = common::scene(scene_name);
    let reset = settings.common.reset_after;
    let name = format!("{scene_name}-neural-nee{nee}");
    let guided = common::assert_converges_to_pt(
        &name,
        &scene,
        Overrides {
            method: Some(Method::NEURAL),
            spp: Some(spp),
            nee,
            seed: Some(300),
            guide: Some(GuideSettings::from(settings)),
            ..Default::default()
        },
    );
    if !nee {
        common::assert_learning_shows(&name, &guided);
    }
    assert!(guided.stats.guide_bytes > 0);
    assert_eq!(guided.stats.image_spp, spp - reset.unwrap_or(0));
}

/// Inference at every vertex.
#[test]
fn neural_converges_to_pt_on_the_cornell_box() {
    unbiased(
        "cornell-box",
        false,
        1024,
        NeuralSettings {
            inference: Inference::Vertices,
            ..small()
        },
    );
}

#[test]
fn neural_with_nee_converges_to_pt_on_the_cornell_box() {
    unbiased("cornell-box", true, 256, small());
}

/// The modes measured not to pay, where qtrace is built with them (the
/// `experiments` feature): the Q-learning target and sampling in
/// proportion to Q; else the defaults.
fn experiments(settings: NeuralSettings) -> NeuralSettings {
    if !cfg!(feature = "experiments") {
        return settings;
    }
    NeuralSettings {
        target: Target::Max,
        common: Common {
            distribution: Distribution::Q,
            ..settings.common.clone()
        },
        ..settings
    }
}

/// Inference at every vertex, with the Q-learning target, sampling in
/// proportion to Q, and the image restarted after 128 training passes.
#[cfg(feature = "experiments")]
#[test]
fn neural_converges_to_pt_on_the_indirectly_lit_room() {
    let mut settings = experiments(NeuralSettings {
        inference: Inference::Vertices,
        ..small()
    });
    settings.common.reset_after = Some(128);
    unbiased("indirect-room", false, 1024, settings);
}

/// Inference at the volumes samples from tables instead of the network, here
/// with the network trained on transitions: the converged image is still pt's.
#[test]
fn neural_inferring_at_volumes_converges_to_pt_on_the_cornell_box() {
    unbiased(
        "cornell-box",
        false,
        1024,
        NeuralSettings {
            inference: Inference::Volumes,
            training: Some(Training::Transitions),
            ..small()
        },
    );
}

/// ... with NEE (with the experiments: the Q-learning target, the tables'
/// max sums, and sampling in proportion to Q).
#[test]
fn neural_inferring_at_volumes_with_nee_converges_to_pt_on_the_indirectly_lit_room() {
    unbiased(
        "indirect-room",
        true,
        256,
        experiments(NeuralSettings {
            inference: Inference::Volumes,
            training: Some(Training::Transitions),
            ..small()
        }),
    );
}

/// Training on the volumes' target means: still pt's image, with and
/// without NEE (whose share the sampling tables leave out).
#[test]
fn neural_training_on_volume_means_converges_to_pt_on_the_cornell_box() {
    unbiased(
        "cornell-box",
        false,
        1024,
        NeuralSettings {
            training: Some(Training::Volumes),
            steps: Some(2),
            ..small()
        },
    );
}

/// Training on the volumes' means, its tables pick NEE's light as Sarsa's do.
#[test]
fn neural_training_on_volume_means_with_nee_converges_to_pt_with_several_lights() {
    unbiased(
        "several-lights",
        true,
        512,
        NeuralSettings {
            training: Some(Training::Volumes),
            ..small()
        },
    );
}

#[test]
fn neural_training_on_volume_means_with_nee_converges_to_pt_on_the_indirectly_lit_room() {
    unbiased(
        "indirect-room",
        true,
        256,
        NeuralSettings {
            training: Some(Training::Volumes),
            ..small()
        },
    );
}

/// Each row training draws from the volumes is a volume's encoded state and
/// that volume's row of mean targets, one per sector (negative means count
/// as 0), and the step that follows leaves a gradient at every sector.
#[test]
fn training_rows_drawn_from_volumes_hold_their_rows_of_target_means() {
    let ctx = common::gpu();
    let scene = common::scene("cornell-box");
    let settings = NeuralSettings {
        training: Some(Training::Volumes),
        volumes: Some(50),
        batch: Some(300),
        ..small()
    };
    let mut guide = NeuralGuide::new(&ctx, &scene, &settings, 5, 64 * 64).unwrap();
    let n = settings.sectors() as usize;
    let means = guide
        .target_means()
        .expect("training on the volumes has means");
    let volumes = means.volumes.clone();
    // A distinct mean per cell; some negative, which a target clamps to 0.
    let q: Vec<f32> = (0..volumes.len() * n)
        .map(|c| ((c / n) * 1000 + c % n) as f32 - 5.0)
        .collect();
    means.upload_q(&ctx, &q).unwrap();
    let mut params = qtrace::shaders::PassParams::default();
    guide.set_params(&mut params, true);
    ctx.submit(None, |rec| guide.record_update(rec, &params))
        .unwrap();
    common::assert_no_validation_errors(&ctx);
    let inputs = guide.network.download_inputs().unwrap();
    let targets = guide.network.download_targets().unwrap();
    let (dense, deltas) = guide.network.download_dense().unwrap();
    let width = guide.network.shape.inputs as usize;
    // A row per volume at most: 50 rows, each a volume drawn at random.
    let rows = volumes.len();
    let mut seen = std::collections::HashSet::new();
    for (row, t) in targets.iter().take(rows).enumerate() {
        // The row's volume is where a one-target row keeps its sector.
        let v = t.sector as usize;
        let volume = &volumes[v];
        let expected = encode(scene.bounds(), volume.position.into(), volume.normal.into());
        assert_close(
            &format!("row {row}'s input"),
            &inputs[row * width..(row + 1) * width],
            &expected,
            1e-5,
        );
        let means_row: Vec<f32> = q[v * n..(v + 1) * n].iter().map(|m| m.max(0.0)).collect();
        assert_eq!(
            &dense[row * n..(row + 1) * n],
            &means_row[..],
            "row {row}'s targets"
        );
        // The step that ran left a gradient at every sector.
        assert!(deltas[row * n..(row + 1) * n].iter().all(|d| *d != 0.0));
        seen.insert(v);
    }
    // Past the volume count the batch holds no rows.
    assert!(deltas[rows * n..(rows + 1) * n].iter().all(|d| *d == 0.0));
    // Drawn at random: many distinct volumes.
    assert!(
        seen.len() > 20,
        "{} distinct volumes in {rows} rows",
        seen.len()
    );
}

/// A training step on rows with a target for every sector (training on the
/// volumes' means) matches the CPU twin: the gradient of the rows' summed
/// losses over all their sectors, then Adam.
#[test]
fn gpu_dense_training_step_matches_cpu() {
    let ctx = common::gpu();
    let mut rng = Lcg(7);
    let mut cpu_params = params(&mut rng);
    let adam = Adam {
        learning_rate: 1e-2,
        ..Adam::default()
    };
    let rows = 200;
    let mut net = Network::new(&ctx, SHAPE, adam, 256, &cpu_params, true).unwrap();
    let n = cpu_params.len();
    let outputs = SHAPE.outputs as usize;
    let x = inputs(&mut rng, rows);
    let targets: Vec<f32> = (0..rows * outputs).map(|_| 3.0 * rng.next()).collect();
    net.upload_dense_batch(&x, &targets).unwrap();
    ctx.submit(None, |rec| net.record_training(rec, 1)).unwrap();
    common::assert_no_validation_errors(&ctx);

    let mut grad = vec![0.0; n];
    let mut losses = Vec::new();
    for (r, row) in x.chunks(SHAPE.inputs as usize).enumerate() {
        let loss = (0..outputs)
            .map(|k| SHAPE.gradient(&cpu_params, row, k, targets[r * outputs + k], &mut grad))
            .sum::<f32>();
        losses.push(loss);
    }
    grad.iter_mut().for_each(|g| *g /= rows as f32);
    let (mut m, mut v) = (vec![0.0; n], vec![0.0; n]);
    let step = Moments {
        m: &mut m,
        v: &mut v,
        step: 1,
    };
    assert_step_matches(&net, "dense step", &losses, &grad, &mut cpu_params, step);
}

/// The tables hold the network's Q at every volume's point and normal, as
/// the CPU twin infers it, and sample in proportion to Q cos(theta) (to
/// within the alias table's rounding to whole units, 2 in 65535).
#[test]
fn volume_tables_hold_the_network_at_the_volumes() {
    let ctx = common::gpu();
    let scene = common::scene("cornell-box");
    let settings = NeuralSettings {
        inference: Inference::Volumes,
        volumes: Some(100),
        ..small()
    };
    let guide = NeuralGuide::new(&ctx, &scene, &settings, 5, 64 * 64).unwrap();
    let shape = guide.network.shape;
    let mut rng = Lcg(11);
    let mut p = shape.init(3, 0.5);
    for layer in &shape.layers() {
        for o in 0..layer.fan_out {
            p[layer.bias(o)] += rng.next() - 0.5;
        }
    }
    guide.network.upload_params(&p).unwrap();
    guide.refresh(&ctx).unwrap();
    common::assert_no_validation_errors(&ctx);
    let table = guide.table().expect("inference at the volumes has tables");
    assert_eq!(table.volumes.len(), 100);
    let q = table.download_q().unwrap();
    let probabilities = table.download_probabilities().unwrap();
    let n = shape.outputs as usize;
    let (a, b) = (settings.common.grid[0], settings.common.grid[1]);
    let cos: Vec<f32> = (0..n as u32)
        .map(|k| sampling::sector_cos(k, a, b))
        .collect();
    for (v, volume) in table.volumes.iter().enumerate() {
        let x = guide.encode(volume.position.into(), volume.normal.into());
        let cpu = shape.forward(&p, &x);
        assert_close(
            &format!("Q at volume {v}"),
            &q[v * n..(v + 1) * n],
            &cpu,
            1e-5,
        );
        let total: f32 = (0..n).map(|k| cpu[k] * cos[k]).sum();
        for k in 0..n {
            let expected = cpu[k] * cos[k] / total;
            let got = probabilities[v * n + k];
            assert!(
                (got - expected).abs() <= 3.0 / 65535.0,
                "volume {v} sector {k}: P {got}, Q cos share {expected}"
            );
        }
    }

    // With NEE the network's output is Q less the share NEE carries: the
    // tables hold the network's output plus that share (their sums need all
    // of Q), and still sample in proportion to the network's output.
    let direct: Vec<f32> = (0..q.len()).map(|i| (i % 7) as f32 * 0.25).collect();
    table.upload_q_direct(&ctx, &direct).unwrap();
    guide.refresh_for(&ctx, true).unwrap();
    common::assert_no_validation_errors(&ctx);
    let q_nee = table.download_q().unwrap();
    let probabilities_nee = table.download_probabilities().unwrap();
    let within = |a: &f32, b: &f32| (a - b).abs() <= 1e-5 * b.abs().max(1.0);
    assert!(q_nee
        .iter()
        .zip(&q)
        .zip(&direct)
        .all(|((x, y), d)| within(x, &(y + d))));
    assert!(probabilities_nee
        .iter()
        .zip(&probabilities)
        .all(|(a, b)| (a - b).abs() <= 3.0 / 65535.0));

    // Where cells' running means of targets have counted visits, the tables
    // blend them with the network: (N mean + m Q) / (N + m).
    let means = guide
        .target_means()
        .expect("training on the volumes has means");
    let mean: Vec<f32> = (0..q.len()).map(|i| 2.0 + (i % 5) as f32).collect();
    let visits: Vec<u32> = (0..q.len() as u32).map(|i| i % 9).collect();
    means.upload_q(&ctx, &mean).unwrap();
    means.upload_visits(&ctx, &visits).unwrap();
    guide.refresh(&ctx).unwrap();
    common::assert_no_validation_errors(&ctx);
    let blended = table.download_q().unwrap();
    let m = settings.prior_visits;
    assert_eq!(m, 4.0);
    for (i, got) in blended.iter().enumerate() {
        let n = visits[i] as f32;
        let expected = (n * mean[i] + m * q[i]) / (n + m);
        assert!(within(got, &expected), "cell {i}: {got} against {expected}");
    }
}

/// The white furnace (every pixel 1): the guided estimator matches it even
/// where guiding cannot help.
#[test]
fn neural_matches_the_white_furnace() {
    let ctx = common::gpu();
    let scene = common::scene("furnace");
    let out = common::render_with(
        &ctx,
        &scene,
        Overrides {
            method: Some(Method::NEURAL),
            spp: Some(128),
            guide: Some(GuideSettings::from(small())),
            ..Default::default()
        },
    );
    common::assert_white_furnace(&out);
}

/// What the trace kernel offers the batch (through the gather pass) is the state encoding of
/// `NeuralGuide::encode` (its CPU twin) at points inside the scene, with
/// unit normals.
fn check_offers(encoding: Encoding) {
    let ctx = common::gpu();
    let scene = common::scene("cornell-box");
    let o = Overrides {
        method: Some(Method::NEURAL),
        spp: Some(1),
        width: Some(32),
        height: Some(32),
        // Paths offer transitions only when the network trains on them.
        guide: Some(GuideSettings::from(NeuralSettings {
            encoding,
            training: Some(Training::Transitions),
            ..small()
        })),
        ..Default::default()
    };
    let renderer = common::run_renderer(&ctx, &scene, o);
    let guide = renderer
        .guide()
        .and_then(|g| g.downcast::<NeuralGuide>())
        .unwrap();
    let inputs = guide.network.download_inputs().unwrap();
    let (lo, hi) = scene.bounds();
    let vertices = scene_vertices(&scene);
    let width = guide.network.shape.inputs as usize;
    let mut rows = 0;
    for row in inputs.chunks(width) {
        // Where the normal is, and the point recovered from the row.
        let (normal_at, p) = match encoding {
            Encoding::Frequency => (3, lo + (Vec3::from_slice(row) + 1.0) * 0.5 * (hi - lo)),
            Encoding::Vertices => (
                3 * vertices.len(),
                vertices[0] - Vec3::from_slice(row) * (hi - lo),
            ),
        };
        let n = Vec3::from_slice(&row[normal_at..]);
        if n == Vec3::ZERO {
            continue; // a row no transition reached
        }
        rows += 1;
        assert!((n.length() - 1.0).abs() < 1e-5, "normal {n} in {row:?}");
        let margin = (hi - lo) * 1e-3;
        assert!(
            p.cmpge(lo - margin).all() && p.cmple(hi + margin).all(),
            "point {p} outside the scene: {row:?}"
        );
        let cpu = guide.encode(p, n);
        for (i, (g, c)) in row.iter().zip(&cpu).enumerate() {
            assert!((g - c).abs() < 2e-4, "input {i}: GPU {g} vs CPU {c}");
        }
    }
    // The first pass offers each path's kept transition with chance
    // batch / (4 pixels), 1/4 here: about 256 rows of 1024 paths.
    assert!((180..=330).contains(&rows), "{rows} rows offered");
}

#[test]
fn trace_kernel_offers_encoded_states() {
    check_offers(Encoding::Frequency);
}

#[cfg(feature = "experiments")]
#[test]
fn trace_kernel_offers_vertex_encoded_states() {
    check_offers(Encoding::Vertices);
}

/// The thesis's encoding, scene vertices relative to the point.
#[cfg(feature = "experiments")]
#[test]
fn neural_with_vertex_encoding_converges_to_pt_on_the_cornell_box() {
    unbiased(
        "cornell-box",
        false,
        512,
        NeuralSettings {
            encoding: Encoding::Vertices,
            ..small()
        },
    );
}

/// χ² test: directions the GPU Neural-Q sampler draws at a state follow the
/// pdf it reports, whose sector probabilities are the CPU network's Q·cos θ
/// (or Q) at that state's encoding, normalised.
fn check_sampler(distribution: Distribution) {
    let ctx = common::gpu();
    let scene = common::scene("cornell-box");
    let settings = NeuralSettings {
        common: Common {
            epsilon: Some(0.25),
            distribution,
            ..Default::default()
        },
        ..small()
    };
    let guide = NeuralGuide::new(&ctx, &scene, &settings, 1, 1024).unwrap();
    // Large output weights make a lumpy distribution.
    let shape = settings.shape();
    let mut params = shape.init(5, 0.1);
    let out = *shape.layers().last().unwrap();
    for o in 0..out.fan_out {
        for i in 0..out.fan_in {
            params[out.weight(o, i)] *= 40.0;
        }
    }
    guide.network.upload_params(&params).unwrap();
    let (point, normal) = (Vec3::new(300.0, 200.0, 250.0), Vec3::new(0.0, 1.0, 0.0));

    let mut rng = Lcg(21);
    let uniforms: Vec<Vec3> = (0..300_000)
        .map(|_| Vec3::new(rng.next(), rng.next(), rng.next()))
        .collect();
    let samples = probe::neural_samples(&ctx, &scene, &guide, point, normal, &uniforms).unwrap();
    common::assert_no_validation_errors(&ctx);

    let [a, b] = settings.common.grid;
    let q = shape.forward(&params, &encode(scene.bounds(), point, normal));
    let w: Vec<f64> = q
        .iter()
        .enumerate()
        .map(|(k, &q)| match distribution {
            Distribution::Qcos => q as f64 * sampling::sector_cos(k as u32, a, b) as f64,
            Distribution::Q => q as f64,
        })
        .collect();
    let total: f64 = w.iter().sum();
    let p: Vec<f64> = w.iter().map(|x| x / total).collect();
    // Lumpy indeed: the test would pass a near-uniform sampler otherwise.
    let largest = p.iter().cloned().fold(0.0, f64::max);
    assert!(largest > 5.0 / p.len() as f64, "largest P(k) {largest}");
    common::assert_mixture_sampler(
        &samples,
        &p,
        settings.common.epsilon(false) as f64,
        settings.common.grid,
    );
}

#[test]
fn neural_sampler_matches_its_pdf() {
    check_sampler(Distribution::Qcos);
}

#[cfg(feature = "experiments")]
#[test]
fn neural_sampler_matches_its_pdf_in_proportion_to_q() {
    check_sampler(Distribution::Q);
}

/// The batch is packed in pixel order from one transition per path, and
/// the output layer's step sums its rows in order: one seed gives one
/// network and one image, bit for bit, with and without NEE.
#[test]
fn neural_is_reproducible_bit_for_bit() {
    let ctx = common::gpu();
    let scene = common::scene("cornell-box");
    for nee in [false, true] {
        let run = || {
            let out = common::render_with(
                &ctx,
                &scene,
                Overrides {
                    method: Some(Method::NEURAL),
                    spp: Some(6),
                    width: Some(48),
                    height: Some(48),
                    nee,
                    seed: Some(8),
                    guide: Some(GuideSettings::from(small())),
                    ..Default::default()
                },
            );
            let losses: Vec<Option<f64>> = out.stats.passes.iter().map(|p| p.loss).collect();
            (out.image, losses.len())
        };
        let a = run();
        for _ in 0..2 {
            assert_eq!(a, run(), "nee {nee}: same seed, different image");
        }
    }
}

/// The shares of BSDF sampling in the tables `neural` samples from after a
/// small render of `scene` (64 spp at 32×32) with `learn` as `learn_epsilon`.
fn neural_bsdf_shares(scene: &str, learn: bool) -> Vec<f32> {
    let renderer = common::run_guided(
        scene,
        GuideSettings::from(NeuralSettings {
            learn_epsilon: Some(learn),
            common: Common {
                epsilon: Some(0.5),
                ..Default::default()
            },
            ..Default::default()
        }),
    );
    let guide = renderer
        .guide()
        .and_then(|g| g.downcast::<NeuralGuide>())
        .unwrap();
    guide.table().unwrap().download_bsdf_shares().unwrap()
}

/// Trained on the volumes' means, the passes that learn run Sarsa's kernel,
/// and the tables paths sample from copy the shares the means learned: in
/// the white furnace, far more BSDF sampling than the starting half.
/// Without learning they stay epsilon.
#[test]
fn tables_learn_their_share_of_bsdf_sampling() {
    let furnace = neural_bsdf_shares("furnace", true);
    let mean = furnace.iter().map(|&s| s as f64).sum::<f64>() / furnace.len() as f64;
    assert!(mean > 0.85, "mean share {mean} in the furnace: {furnace:?}");
    assert!(
        furnace.iter().all(|s| (0.047..=0.953).contains(s)),
        "{furnace:?}"
    );
    let fixed = neural_bsdf_shares("furnace", false);
    assert!(fixed.iter().all(|&s| s == 0.5), "{fixed:?}");
}

/// With `steps` unset, the first pass trains one step per 4096 pixels (at
/// least 4) and measures what a step and a trace pass cost on the device;
/// the passes after it train as many steps as that fits (`fitted_steps`),
/// which the stats say. Given steps stay as given.
#[test]
fn training_steps_are_sized_by_the_first_pass() {
    let ctx = common::gpu();
    let scene = common::scene("cornell-box");
    let render = |steps: Option<u32>| {
        common::render_with(
            &ctx,
            &scene,
            Overrides {
                method: Some(Method::NEURAL),
                spp: Some(8),
                width: Some(48),
                height: Some(48),
                seed: Some(3),
                guide: Some(GuideSettings::from(NeuralSettings { steps, ..small() })),
                ..Default::default()
            },
        )
    };
    let steps_run = |out: &qtrace::RenderOutput| {
        out.stats
            .gpu_passes
            .iter()
            .find(|t| t.name == "mlp training")
            .map_or(0, |t| t.count)
    };
    // Passes 0-4 and 6 of 8 train (`train_thin_after` 4).
    let out = render(None);
    if ctx.info().timestamps {
        let fit = out.stats.guide_fit.clone().expect("a fit with timestamps");
        assert!((4..=64).contains(&fit.training_steps), "{fit:?}");
        assert!(fit.step_ms > 0.0 && fit.pass_ms > 0.0, "{fit:?}");
        assert_eq!(
            fitted_steps(fit.pass_ms, fit.step_ms, 4),
            Some(fit.training_steps)
        );
        assert_eq!(steps_run(&out), 4 + 5 * fit.training_steps as u64);
    } else {
        eprintln!(
            "skipped the fit's checks: {} has no timestamps",
            ctx.info().name
        );
        assert!(out.stats.guide_fit.is_none());
    }
    let pinned = render(Some(3));
    assert!(pinned.stats.guide_fit.is_none());
    if ctx.info().timestamps {
        assert_eq!(steps_run(&pinned), 6 * 3);
    }
}
