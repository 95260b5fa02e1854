# m2smap — the two commands a fresh clone needs are `make demo` and `make test`.
CARGO ?= cargo
TARGET_MCU := thumbv7em-none-eabihf
DEMO := target/demo

.PHONY: demo test bench core-nostd budget

## Map a synthetic scene the project makes itself (no ../shared needed) and print a summary.
demo:
	$(CARGO) build --release -p m2smap
	./target/release/m2smap synth --scene tabletop --frames 10 --seed 1 --out $(DEMO)/tabletop
	./target/release/m2smap run $(DEMO)/tabletop --out $(DEMO)/tabletop-run
	./target/release/m2smap run $(DEMO)/tabletop --out $(DEMO)/tabletop-run-mcu --profile mcu
	@echo "outputs: $(DEMO)/tabletop-run/summary.json and frames.jsonl"

## Every test: the no_std core for the Cortex-M7 target, then the workspace tests (release: the real-data runs are fast).
test: core-nostd
	$(CARGO) test --release --workspace

## The core must build for a bare-metal Cortex-M7 target: no std, no allocator.
core-nostd:
	@if ! rustup target list --installed 2>/dev/null | grep -q $(TARGET_MCU); then \
		rustup target add $(TARGET_MCU) || { echo "make test: cannot install $(TARGET_MCU); the no_std build is NOT checked"; exit 1; }; fi
	$(CARGO) build -p m2smap-core --target $(TARGET_MCU) --release

## Median time per stage on the cabinet and redkitchen frames (../shared/data) and on synthetic frames.
bench:
	$(CARGO) bench -p m2smap --bench stages

## Print the mcu memory table (paste into memory_budget.md when pools change).
budget:
	$(CARGO) run --release -q -p m2smap -- budget
