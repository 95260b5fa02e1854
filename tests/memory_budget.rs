//! `memory_budget.md` must state the pools exactly as the code sizes them, within the 512 KiB budget.

use m2smap::budget;
use m2smap_core::profile::{McuStorage, MCU_BUDGET_BYTES, MCU_TOTAL_BYTES};

#[test]
fn budget_table_matches_the_code() {
    let doc = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../memory_budget.md")).unwrap();
    let table = budget::table();
    assert!(
        doc.contains(&table),
        "memory_budget.md is out of date; regenerate the table with `m2smap budget`:\n{table}"
    );
    let world = budget::world_table();
    assert!(doc.contains(&world), "memory_budget.md: the world-map table is out of date (`m2smap budget`):\n{world}");
}

#[test]
fn mcu_profile_fits_its_budget() {
    let pools: usize = McuStorage::POOLS.iter().map(|&(_, cap, size)| cap * size).sum();
    assert_eq!(pools, McuStorage::BYTES, "every byte of the storage belongs to a listed pool");
    // MCU_TOTAL_BYTES <= MCU_BUDGET_BYTES is a `const` assertion in core/src/profile.rs: the build fails first.
    println!("mcu total {MCU_TOTAL_BYTES} of {MCU_BUDGET_BYTES} bytes");
}
