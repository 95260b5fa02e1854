use m2smap::dataset::Dataset;
use m2smap::masks::{read_frame_masks, LabelTable};
use m2smap_core::{HostStorage, Mapper, Params, Variant, linalg};
fn main() {
    let d = Dataset::open(std::path::Path::new("../shared/data/tum_fr3_cabinet"), None).unwrap();
    let mut st = bytemuck::zeroed_box::<HostStorage>();
    let variant = Variant::from_name(&std::env::args().nth(1).unwrap_or("full".into())).unwrap();
    let mut mapper = Mapper::new(&mut *st, Params { variant, alpha_r: 1.0, alpha_s: 1.0, alpha_c: 1.0, ..Params::default() }).unwrap();
    let mut labels = LabelTable::default();
    for k in 0..20 {
        let f = d.load(k).unwrap();
        let m = read_frame_masks(&d.root.join("masks"), &d.frames[k].stem, 640, 480, &mut labels).unwrap();
        let pose = d.frames[k].pose.unwrap();
        mapper.process(f.view_posed(&d.camera, Some(&pose)), m.as_ref().map(|m| m.view())).unwrap();
        let o = mapper.objects()[0];
        let p = pose.to_core();
        let rw = linalg::mat_mul(&p.rotation, &o.sq.rotation);
        let cw = p.to_world(o.sq.centre);
        let t = mapper.tracks()[0];
        let axes: Vec<String> = (0..3).map(|i| { let a = linalg::column(&rw, i); format!("{:.2}@({:.2},{:.2},{:.2})", o.sq.scales[i], a[0], a[1], a[2]) }).collect();
        println!("{k}: {}", axes.join(" "));
        if false { println!("{k}: state {} E {:.2e} scales {:?} eps {:?} centre_w {:?} z-axis_w {:?} track scales {:?} jump {:.1}", o.sq_state, o.sq_error, o.sq.scales.map(|x| (x*100.0).round()/100.0), o.sq.eps.map(|x| (x*100.0).round()/100.0), cw.map(|x| (x*100.0).round()/100.0), linalg::column(&rw, 2).map(|x| (x*100.0).round()/100.0), t.sq.scales.map(|x| (x*100.0).round()/100.0), t.last_jump_deg); }
    }
}
