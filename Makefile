# m2smap — the two commands a fresh clone needs are `make demo` and `make test`.
SHELL := /bin/bash
.SHELLFLAGS := -eo pipefail -c
CARGO ?= cargo
TARGET_MCU := thumbv7em-none-eabihf
DEMO := target/demo
SHARED := ../shared/data
FW_FRAMES := $(CURDIR)/target/fw-frames
FW_ELF := firmware/target/$(TARGET_MCU)/release/m2smap-firmware
# The host decoder of the firmware's defmt log (its own workspace; built from here, so it targets the host).
FW_DECODE_MANIFEST := firmware/defmt-decode/Cargo.toml
FW_DECODE := firmware/defmt-decode/target/debug/m2smap-defmt-decode
QEMU := timeout 600 qemu-system-arm -machine mps2-an500 -nographic -semihosting-config enable=on,target=native -icount shift=0

.PHONY: demo test lint bench eval sweep core-nostd budget firmware firmware-check firmware-profile fuzz
FUZZ_SECONDS ?= 600
FUZZ_TARGETS := wire_decode mapper_frame masks_parse lists_parse

## Map a synthetic scene the project makes itself (no ../shared needed) and print a summary.
demo:
	$(CARGO) build --release -p m2smap
	./target/release/m2smap synth --scene tabletop --frames 10 --seed 1 --out $(DEMO)/tabletop
	./target/release/m2smap run $(DEMO)/tabletop --out $(DEMO)/tabletop-run --world $(DEMO)/tabletop-world
	./target/release/m2smap run $(DEMO)/tabletop --out $(DEMO)/tabletop-run-mcu --profile mcu
	./target/release/m2smap render $(DEMO)/tabletop --frame 9 --world --out $(DEMO)/tabletop-world.png
	./target/release/m2smap render $(DEMO)/tabletop --frame 5 --out $(DEMO)/tabletop-frame5.png
	./target/release/m2smap export $(DEMO)/tabletop --frame 5 --ply $(DEMO)/tabletop-frame5.ply
	@if [ -d $(SHARED)/tum_fr3_cabinet ]; then \
		./target/release/m2smap render $(SHARED)/tum_fr3_cabinet --frame 12 --out $(DEMO)/cabinet-frame12.png; fi
	@echo "outputs: $(DEMO)/tabletop-run/summary.json and frames.jsonl, the world map in $(DEMO)/tabletop-world, renders and a PLY in $(DEMO)"

## Every test: the no_std core for the Cortex-M7 target, the firmware under QEMU (when available), then the
## workspace tests (release: the real-data runs are fast).
test: lint core-nostd firmware-check
	@rm -f target/skipped-tests.txt
	$(CARGO) test --release --workspace
	@if [ -s target/skipped-tests.txt ]; then \
		echo "make test: $$(wc -l < target/skipped-tests.txt) tests SKIPPED their real-data part (../shared/data is absent):"; \
		sort target/skipped-tests.txt | sed 's/^/  /'; \
	else echo "make test: no test skipped"; fi

## Formatting (rustfmt.toml) of the workspace, the firmware and its decoder, clippy with every warning an
## error (the core's deny(clippy::indexing_slicing, ...) included) over every target of the workspace, and the
## API docs with every rustdoc warning an error (no broken or private intra-doc links).
lint:
	$(CARGO) fmt --check
	cd firmware && $(CARGO) fmt --check
	cd firmware/defmt-decode && $(CARGO) fmt --check
	$(CARGO) clippy --workspace --all-targets -- -D warnings
	RUSTDOCFLAGS="-D warnings" $(CARGO) doc --no-deps --workspace -q

## The core must build for a bare-metal Cortex-M7 target: no std, no allocator.
core-nostd:
	@if ! rustup target list --installed 2>/dev/null | grep -q $(TARGET_MCU); then \
		rustup target add $(TARGET_MCU) || { echo "make test: cannot install $(TARGET_MCU); the no_std build is NOT checked"; exit 1; }; fi
	$(CARGO) build -p m2smap-core --target $(TARGET_MCU) --release

## How `full` generalises: every synthetic scene x seeds 1-3 x masks eroded by 2 px (10 % missing) or dilated by
## 2 px, scored against the superquadric issue's targets; writes target/sweep/sweep.md. Other grids through
## SWEEP_ARGS, e.g. SWEEP_ARGS="--seeds 4,5 --masks erode1,erode3,dilate1,dilate3".
SWEEP_ARGS ?=
sweep:
	$(CARGO) run --release -p m2smap -- sweep --out target/sweep $(SWEEP_ARGS)

## Median time per stage on the cabinet and redkitchen frames (../shared/data) and on synthetic frames.
bench:
	$(CARGO) bench -p m2smap --bench stages

## The evaluation suite: every variant on the synthetic scenes (perfect masks, ground truth) and the real cabinet
## frames; writes $(EVAL)/report.md (Tables I and II) and $(EVAL)/comparison.svg/.png.
EVAL := target/eval
EVAL_SCENES ?= tabletop shelf desk kitchen clutter dining
EVAL_FRAMES ?= 20
eval:
	$(CARGO) build --release -p m2smap
	for s in $(EVAL_SCENES); do ./target/release/m2smap synth --scene $$s --frames $(EVAL_FRAMES) --seed 1 --out $(EVAL)/data/$$s; done
	./target/release/m2smap eval $(addprefix $(EVAL)/data/,$(EVAL_SCENES)) \
		$$([ -d $(SHARED)/tum_fr3_cabinet ] && echo $(SHARED)/tum_fr3_cabinet || echo "skipping $(SHARED)/tum_fr3_cabinet (not found)" >&2) \
		--out $(EVAL)

## Print the mcu memory table (paste into memory_budget.md when pools change).
budget:
	$(CARGO) run --release -q -p m2smap -- budget

## The core in a Cortex-M7 image (mcu profile, 512 KiB RAM region) on 3 real cabinet frames under QEMU mps2-an500:
## map bytes, world deltas and the geometric segmenter's masks must equal the host's (CRC per frame), instructions
## per frame and stage (and of the segmenter) are printed, and the counting
## global allocator (embedded-alloc) must have seen 0 heap allocations in every frame's pipeline.
## The image logs through defmt over semihosting stdout (every line, the map CRC lines too: they are one short line
## per frame, not bulk bytes); the raw stream is kept in target/fw-run.defmt and decoded by firmware/defmt-decode
## (defmt-decoder, the library defmt-print is built on: about 1 min to build on 2 cores, `cargo install defmt-print` 4.5 min).
firmware:
	$(CARGO) run --release -q -p m2smap -- firmware-frames $(SHARED)/tum_fr3_cabinet --frames 3 --out $(FW_FRAMES)
	cd firmware && M2SMAP_FRAMES=$(FW_FRAMES) $(CARGO) build --release --locked
	$(CARGO) build -q --locked --manifest-path $(FW_DECODE_MANIFEST)
	arm-none-eabi-size -A $(FW_ELF) | grep -E '^\.(vector_table|text|rodata|data|bss|frames) '
	@reserve=$$((16#$$(arm-none-eabi-nm $(FW_ELF) | awk '$$3 == "_stack_reserve" { print $$1 }'))); \
		arm-none-eabi-size -A $(FW_ELF) | awk -v reserve=$$reserve '$$1 == ".data" || $$1 == ".bss" { ram += $$2 } \
		END { printf "RAM: .data + .bss %d bytes + %d stack reserve = %d of 524288 bytes (%.1f %%)\n", ram, reserve, ram + reserve, (ram + reserve) / 5242.88 }'
	$(QEMU) -kernel $(FW_ELF) | tee target/fw-run.defmt | $(FW_DECODE) $(FW_ELF) | tee target/fw-run.txt
	grep -E '^frame [0-9]+ (map|world delta|segment [0-9]+ instances) ' target/fw-run.txt | diff -u $(FW_FRAMES)/expected.txt -
	@reserve=$$((16#$$(arm-none-eabi-nm $(FW_ELF) | awk '$$3 == "_stack_reserve" { print $$1 }'))); \
		hw=$$(sed -n 's/^stack high-water \([0-9]*\) bytes.*/\1/p' target/fw-run.txt); \
		[ -n "$$hw" ] && [ "$$hw" -le "$$reserve" ] || { echo "firmware: FAILED: stack high-water $$hw bytes > the $$reserve-byte reserve"; exit 1; }
	@grep -q '^floor self-check: the core.s floor equals libm.s on [0-9]* values' target/fw-run.txt || \
		{ echo "firmware: FAILED: the floor self-check did not pass (or did not run)"; exit 1; }
	@grep -q '^spread self-check: the core.s spread update equals the portable one on [0-9]* points' target/fw-run.txt || \
		{ echo "firmware: FAILED: the spread self-check did not pass (or did not run)"; exit 1; }
	@grep -qx 'heap allocations during process: 0' target/fw-run.txt || \
		{ echo "firmware: FAILED: the core allocated on the heap during process (or the count is missing)"; exit 1; }
	@echo "firmware: the Cortex-M7 maps, world deltas and segmenter masks equal the host's byte for byte ($$(grep -c '^frame [0-9]* map' target/fw-run.txt) frames); 0 heap allocations during process"

## Instructions per function of the firmware image `make firmware` built (its three frames and the segmenter):
## QEMU logs every translated block and every execution (several GB in /tmp), firmware/tools/profile.py sums them.
firmware-profile:
	$(QEMU) -d in_asm,exec,nochain -D /tmp/m2smap-fw-exec.log -kernel $(FW_ELF) > /dev/null
	python3 firmware/tools/profile.py /tmp/m2smap-fw-exec.log $(FW_ELF) 40
	rm -f /tmp/m2smap-fw-exec.log

## `make firmware` when QEMU and the shared frames are here; under CI their absence is an error.
firmware-check:
	@if command -v qemu-system-arm >/dev/null && command -v arm-none-eabi-size >/dev/null && [ -d $(SHARED)/tum_fr3_cabinet ]; then \
		$(MAKE) --no-print-directory firmware; \
	elif [ "$$CI" = "true" ]; then \
		echo "error: CI needs qemu-system-arm, binutils-arm-none-eabi and $(SHARED) for the firmware check"; exit 1; \
	else \
		echo "make test: firmware check SKIPPED (needs qemu-system-arm, arm-none-eabi-size and $(SHARED)/tum_fr3_cabinet)"; \
	fi

## Fuzz every target for FUZZ_SECONDS each (nightly + cargo-fuzz; `cargo install cargo-fuzz`). The committed seeds
## and every crash ever found are replayed by `cargo test` (tests/fuzz_replay.rs) without nightly.
fuzz:
	@for t in $(FUZZ_TARGETS); do fuzz/run.sh $$t $(FUZZ_SECONDS); done
