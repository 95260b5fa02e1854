use m2smap::dataset::Dataset;
use m2smap::masks::LabelTable;
use m2smap::run::{map_frame, MaskSource, SegmenterBuffers};
use m2smap_core::{Mapper, Params};
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let ds = Dataset::open(std::path::Path::new(&args[1]), None).unwrap();
    let from: usize = args[2].parse().unwrap();
    let to: usize = args[3].parse().unwrap();
    let seg = args.get(4).map(|s| s == "seg").unwrap_or(false);
    let mut storage = bytemuck::zeroed_box::<m2smap_core::HostStorage>();
    let mut mapper = Mapper::new(&mut *storage, Params::default()).unwrap();
    let mut labels = LabelTable::default();
    let mut sb = SegmenterBuffers::default();
    let masks_dir = ds.root.join("masks");
    for i in from..=to {
        let src = if seg { MaskSource::Segmenter } else { MaskSource::Files(Some(&masks_dir)) };
        let m = map_frame(&mut mapper, &ds, i, src, &mut labels, &mut sb).unwrap();
        println!("frame {i} ms {:.1} planes {}", m.ms, mapper.planes().len());
        for p in mapper.planes() { println!("  plane n {:?} c {:?}", p.normal, p.centroid); }
        for o in mapper.objects() {
            println!("  obj inst {} pts {} state {} err {:.3} scales {:?} eps {:?} centre {:?} track {}", o.instance, o.points, o.sq_state, o.sq_error, o.sq.scales, o.sq.eps, o.sq.centre, o.track);
        }
    }
}
