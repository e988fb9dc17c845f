use rlpkg_calib::loss::LossWeights;
use rlpkg_calib::objective::*;
use std::time::Instant;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let between: usize = args[1].parse().unwrap();
    let dt: Option<f64> = args[2].parse().ok();
    let secs: f64 = args[3].parse().unwrap();
    let ncand: usize = args[4].parse().unwrap();
    let ids: Vec<&str> = args[5].split(',').collect();
    let ds = rlpkg_mocap::Dataset::open(std::path::Path::new("data/deformable-sim-real")).unwrap();
    let trajs: Vec<_> = ids.iter().map(|id| ds.load(id).unwrap()).collect();
    let scene = load_scene("reference", Some(between), dt).unwrap();
    let names: Vec<String> = vec!["k_tri_e".into()];
    let obj = SimObjective::new(&scene, names, &trajs, LossWeights::default(), Some(secs)).unwrap();
    let model = std::sync::Arc::new(rlpkg_sim::Model::new(&scene).unwrap());
    let params: Vec<_> = (0..ncand)
        .map(|i| obj.params_for(&[2e5 * (1.0 + i as f64)]))
        .collect();
    let t0 = Instant::now();
    struct P;
    impl Observer for P {
        fn frame(&mut self, o: &FrameObservation) {
            if o.frame % 40 == 0 {
                let m = &o.simulated_points;
                let my = m.iter().map(|p| p[1]).sum::<f64>() / m.len() as f64;
                println!(
                    "c{} t{} k{} disc {:?} sim marker mean y {:.4} cups y {:.4}",
                    o.candidate,
                    o.target,
                    o.frame,
                    o.disc.position,
                    my,
                    o.simulator.cup_positions(o.env)[0][1]
                );
            }
        }
    }
    let out = rollout(&model, obj.targets(), &params, &mut P).unwrap();
    let t = &obj.targets()[0];
    for k in [0usize, 40, 80, 120] {
        let my = t.markers[k].iter().map(|p| p[1]).sum::<f64>() / t.markers[k].len() as f64;
        println!("rec k{k} object {:?} markers mean y {:.4}", t.object[k], my);
    }
    println!("placement {:?}", t.placement);
    let el = t0.elapsed().as_secs_f64();
    for (c, o) in out.iter().enumerate() {
        for r in o {
            println!(
                "cand {c} {} frames {} cd {:.5} mse {:.6} div {:?}",
                r.loss.id,
                r.loss.frames.len(),
                r.loss.mean_chamfer(),
                r.loss.mean_object_sq(),
                r.diverged
            );
        }
    }
    println!(
        "wall {el:.2}s envs {} particles {}",
        params.len() * trajs.len(),
        model.num_particles()
    );
}
