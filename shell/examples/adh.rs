use std::collections::HashMap;
use m2smap::dataset::Dataset;
use m2smap::masks::{read_frame_masks, LabelTable};
use m2smap_core::{HostStorage, Mapper, Params, Variant};
use m2smap_core::supervoxel::is_assigned;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let k: usize = args[1].parse().unwrap();
    let variant = Variant::from_name(&args[2]).unwrap();
    let d = Dataset::open(std::path::Path::new("../shared/data/tum_fr3_cabinet"), None).unwrap();
    let f = d.load(k).unwrap();
    let mut labels = LabelTable::default();
    let m = read_frame_masks(&d.root.join("masks"), &d.frames[k].stem, 640, 480, &mut labels).unwrap().unwrap();
    let mut st = bytemuck::zeroed_box::<HostStorage>();
    let mut mapper = Mapper::new(&mut *st, Params { variant, ..Params::default() }).unwrap();
    let view = f.view(&d.camera);
    let rep = *mapper.process(view, Some(m.view())).unwrap(); println!("cuts {} gaussians {}", rep.mask_cuts, rep.gaussians);
    let checked = mapper.check(view, Some(m.view())).unwrap();
    let gs = mapper.gaussians();
    let mut per_g: Vec<HashMap<u16,u32>> = vec![HashMap::new(); gs.len()];
    mapper.for_each_labelled_point(&checked, |p, v| { if let Some(v) = v.filter(|v| is_assigned(v.gaussian)) { *per_g[v.gaussian as usize].entry(m.id_at(p.u,p.v)).or_insert(0) += 1; } });
    let mut cl: HashMap<u16, Vec<usize>> = HashMap::new();
    for (i,g) in gs.iter().enumerate() { cl.entry(g.cluster).or_default().push(i); }
    for (c, mem) in cl { let mut tot: HashMap<u16,u32> = HashMap::new(); for &i in &mem { for (l,n) in &per_g[i] { *tot.entry(*l).or_insert(0)+=n; } }
       let sup: u32 = tot.values().sum(); let th = 20u32.max((sup as f64*0.1).ceil() as u32);
       if tot.values().filter(|&&n| n>=th).count() >= 2 { println!("cluster {c} support {sup} labels {tot:?}");
         for &i in &mem { let g=&gs[i]; println!("   g{i} n={} inst={} rho={:.2} role={} labels={:?} sig={:?} n={:?}", g.count, g.instance, g.support_ratio, g.role, per_g[i], g.sigmas(), g.axes[2]); } } }
}
