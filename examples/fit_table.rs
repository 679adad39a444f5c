//! Can the Neural-Q network represent what Sarsa learns, and does it guide
//! as well once it does? On the indirectly lit room at 128×128 (256 volumes),
//! this renders `pt` and `sarsa` at 256 spp, then fits a network (on the
//! CPU, with the reference MLP of `src/guide/mlp.rs`) to Sarsa's final Q at
//! every volume, and renders with that network frozen at the volumes from
//! the first pass, and with Sarsa's final table frozen, against a `pt --nee`
//! reference of 2048 spp. Run from the repository root:
//!
//!   cargo run --release --example fit_table -- [WIDTH=16] [STEPS=3000]
//!
//! A measurement for the README, not a test.
use glam::Vec3;
use qtrace::gpu::{ContextOptions, GpuContext};
use qtrace::guide::mlp::{Adam, MlpShape};
use qtrace::guide::neural::{encode, Inference};
use qtrace::guide::{
    Common, GuideSettings, NeuralGuide, NeuralSettings, SarsaGuide, SarsaSettings,
};
use qtrace::render::{Method, Overrides, RenderSettings, Renderer};
use qtrace::Scene;

fn settings(
    scene: &Scene,
    method: Method,
    nee: bool,
    spp: u32,
    guide: Option<GuideSettings>,
) -> RenderSettings {
    RenderSettings::resolve(
        scene,
        &Overrides {
            method: Some(method),
            spp: Some(spp),
            width: Some(128),
            height: Some(128),
            nee,
            seed: Some(7),
            guide,
            ..Default::default()
        },
    )
    .unwrap()
}

fn main() {
    let width: u32 = std::env::args().nth(1).map_or(16, |s| s.parse().unwrap());
    let steps: u32 = std::env::args().nth(2).map_or(3000, |s| s.parse().unwrap());
    let ctx = GpuContext::new(&ContextOptions {
        device: None,
        validation: false,
        reads: None,
    })
    .unwrap();
    let scene = Scene::load("scenes/indirect-room.toml").unwrap();
    let reference = Renderer::new(&ctx, &scene, settings(&scene, Method::PT, true, 2048, None))
        .unwrap()
        .run(&mut |_| {})
        .unwrap()
        .image;
    let rel = |img: &qtrace::image::Image| qtrace::image::compare(img, &reference).unwrap().rel_mse;
    let pt = Renderer::new(&ctx, &scene, settings(&scene, Method::PT, false, 256, None))
        .unwrap()
        .run(&mut |_| {})
        .unwrap();
    println!("pt 256 spp relMSE {:.4}", rel(&pt.image));
    let mut sarsa = Renderer::new(
        &ctx,
        &scene,
        settings(&scene, Method::SARSA, false, 256, None),
    )
    .unwrap();
    let out = sarsa.run(&mut |_| {}).unwrap();
    println!("sarsa 256 spp relMSE {:.4}", rel(&out.image));
    let g = sarsa.guide().unwrap().downcast::<SarsaGuide>().unwrap();
    let q = g.download_q().unwrap();
    let vols = g.volumes.clone();
    let n = 144usize;
    // The ideal table from the start: Sarsa's final Q, frozen.
    let frozen = GuideSettings::from(SarsaSettings {
        common: Common {
            freeze_after: Some(0),
            ..Default::default()
        },
        ..Default::default()
    });
    let mut fs = Renderer::new(
        &ctx,
        &scene,
        settings(&scene, Method::SARSA, false, 256, Some(frozen)),
    )
    .unwrap();
    fs.guide()
        .unwrap()
        .downcast::<SarsaGuide>()
        .unwrap()
        .upload_q(&ctx, &q)
        .unwrap();
    println!(
        "sarsa's final table, frozen from the start: relMSE {:.4}",
        rel(&fs.run(&mut |_| {}).unwrap().image)
    );
    // Fit the network to the table on the CPU: Adam on minibatches of 16
    // volumes, every sector's squared error.
    let shape = MlpShape {
        inputs: 32,
        width,
        hidden: 2,
        outputs: n as u32,
    };
    let bounds = scene.bounds();
    let xs: Vec<Vec<f32>> = vols
        .iter()
        .map(|v| encode(bounds, Vec3::from(v.position), Vec3::from(v.normal)))
        .collect();
    let mut p = shape.init(3, 0.01);
    let (mut m, mut vv) = (vec![0.0; p.len()], vec![0.0; p.len()]);
    let adam = Adam {
        learning_rate: 3e-3,
        ..Default::default()
    };
    let total: f64 = q.iter().map(|&x| (x.max(0.0) as f64).powi(2)).sum();
    let mut seed = 1u64;
    for t in 1..=steps {
        let mut grad = vec![0.0; p.len()];
        for _ in 0..16 {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let v = ((seed >> 33) as usize) % vols.len();
            for k in 0..n {
                shape.gradient(&p, &xs[v], k, q[v * n + k].max(0.0), &mut grad);
            }
        }
        grad.iter_mut().for_each(|g| *g /= 16.0 * n as f32);
        adam.step(&mut p, &mut m, &mut vv, &grad, t);
        if t % 1000 == 0 || t == steps {
            let err: f64 = (0..vols.len())
                .map(|v| {
                    let o = shape.forward(&p, &xs[v]);
                    (0..n)
                        .map(|k| ((o[k] - q[v * n + k].max(0.0)) as f64).powi(2))
                        .sum::<f64>()
                })
                .sum();
            println!("step {t}: relative squared fit error {:.3}", err / total);
        }
    }
    let neural = GuideSettings::from(NeuralSettings {
        width,
        inference: Inference::Volumes,
        common: Common {
            freeze_after: Some(0),
            ..Default::default()
        },
        ..Default::default()
    });
    let mut nr = Renderer::new(
        &ctx,
        &scene,
        settings(&scene, Method::NEURAL, false, 256, Some(neural)),
    )
    .unwrap();
    let ng = nr.guide().unwrap().downcast::<NeuralGuide>().unwrap();
    ng.network.upload_params(&p).unwrap();
    ng.refresh(&ctx).unwrap();
    println!(
        "network fit to the table, frozen from the start: relMSE {:.4}",
        rel(&nr.run(&mut |_| {}).unwrap().image)
    );
}
