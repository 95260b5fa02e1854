//! The memory budget table of the `mcu` profile, as `memory_budget.md` shows it.

use m2smap_core::profile::{McuStorage, MCU_BUDGET_BYTES, MCU_TOTAL_BYTES};

/// One row: pool name, capacity, bytes per element, bytes.
pub fn rows() -> Vec<(String, usize, usize, usize)> {
    McuStorage::POOLS.iter().map(|&(id, cap, size)| (id.name().to_owned(), cap, size, cap * size)).collect()
}

/// The Markdown table (pools, mapper state, total, budget) that `memory_budget.md` must contain verbatim.
pub fn table() -> String {
    let mut s = String::from("| pool | capacity | bytes/element | bytes |\n|---|---:|---:|---:|\n");
    for (name, cap, size, bytes) in rows() {
        s.push_str(&format!("| {name} | {cap} | {size} | {bytes} |\n"));
    }
    let pools: usize = rows().iter().map(|r| r.3).sum();
    let mapper = MCU_TOTAL_BYTES - pools;
    s.push_str(&format!("| mapper state (params, pool headers, report) | 1 | {mapper} | {mapper} |\n"));
    s.push_str(&format!(
        "| **total** | | | **{MCU_TOTAL_BYTES}** ({:.1} KiB of {} KiB, {:.1} %) |\n",
        MCU_TOTAL_BYTES as f64 / 1024.0,
        MCU_BUDGET_BYTES / 1024,
        100.0 * MCU_TOTAL_BYTES as f64 / MCU_BUDGET_BYTES as f64
    ));
    s
}

/// The world-map storage table (`memory_budget.md`): each pool of the `mcu` and `host` world profiles.
pub fn world_table() -> String {
    use m2smap_core::world::{HostWorld, McuWorld, WorldGaussian, WorldObject, WorldPlane};
    use std::mem::size_of;
    let mut s = String::from("| pool | mcu capacity | host capacity | bytes/element | mcu bytes | host bytes |\n");
    s.push_str("|---|---:|---:|---:|---:|---:|\n");
    let pools = [
        ("world planes", McuWorld::PLANES, HostWorld::PLANES, size_of::<WorldPlane>()),
        ("world objects", McuWorld::OBJECTS, HostWorld::OBJECTS, size_of::<WorldObject>()),
        ("world Gaussians", McuWorld::GAUSSIANS, HostWorld::GAUSSIANS, size_of::<WorldGaussian>()),
        ("pending removals", McuWorld::REMOVALS, HostWorld::REMOVALS, size_of::<(u8, u32)>()),
    ];
    for (name, mcu, host, size) in pools {
        s.push_str(&format!("| {name} | {mcu} | {host} | {size} | {} | {} |\n", mcu * size, host * size));
    }
    s.push_str(&format!("| **total** | | | | **{}** | **{}** |\n", McuWorld::BYTES, HostWorld::BYTES));
    s
}
