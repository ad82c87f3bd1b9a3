# SaarCOR in Amaranth — top-level commands. Each target sets up what it needs by itself.
VENV  ?= .venv
PY    := $(VENV)/bin/python
STAMP := $(VENV)/.setup-done
# the `saarcor` command line (pyproject's [project.scripts]; `saarcor --help`)
SAARCOR := $(VENV)/bin/saarcor
# the commands' defaults (saarcor/args.py: SCENE, RES_QUICK for quick checks)
SCENE ?= scenes/cornell.toml
RES   ?= 128x96
OUT   ?= build/sim

.PHONY: setup test sim bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml scripts/setup.sh
	scripts/setup.sh

## make test: the whole test suite (what CI runs), on every core (pytest-xdist; Verilator
##   builds are shared between workers through a file lock)
TEST_JOBS ?= auto
test: setup
	$(PY) -m pytest -q -n $(TEST_JOBS)

## make sim: a frame through the whole chip (RGS, RTCs, caches, bus, SDRAM model), every ray
##   checked against the golden model -> $(OUT)/image.png, stats.json, usage.png, rays/hits.npz.
##   make sim SCENE=scenes/office.toml RES=256x192 RTCS=2 THREADS=8 BACKEND=verilator|amaranth
##            TRACE=wave.fst CONFIG="--trav-cache-kb 16 --mem-latency 30"
##   EYE_ONLY=1: eye rays only (default: the slaves also make the shadow and reflection rays)
RTCS    ?=
THREADS ?=
BACKEND ?= verilator
TRACE   ?=
EYE_ONLY ?=
EYE_ONLY_FLAG := $(if $(EYE_ONLY),--eye-only)
sim: setup
	$(SAARCOR) sim --scene $(SCENE) --res $(RES) --out $(OUT) --backend $(BACKEND) \
	    $(if $(RTCS),--rtcs $(RTCS)) $(if $(THREADS),--threads $(THREADS)) \
	    $(if $(TRACE),--trace $(TRACE)) $(EYE_ONLY_FLAG) $(CONFIG)

## make bench: long sweeps and speed measurements, written to build/bench/
BENCH_SCENE ?= scenes/office.toml
# the golden model's speed against Embree: a real mesh if one is at hand (the README's figures
# use the Stanford dragon), else the procedural terrain
BENCH_MESH  ?= $(firstword $(wildcard $(SAARCOR_MESHES)/dragon.obj ../shared/meshes/dragon.obj))
# the stall bench's small chip (2 RTCs, 1 KB caches: misses and evictions on every frame)
CHIP_SMALL  ?= --rtcs 2 --threads 2 --tile-w 4 --tile-h 4 --trav-subunits 2 --trav-cache-kb 1 \
	       --list-cache-kb 1 --int-cache-kb 9 --mem-latency 8
bench: setup
	mkdir -p build/bench
	$(SAARCOR) bench model --out build/bench $(if $(BENCH_MESH),--scene $(BENCH_MESH))
	$(SAARCOR) bench memory --scene $(BENCH_SCENE) --out build/bench
	$(SAARCOR) bench threads --out build/bench
	$(SAARCOR) bench threads --scene scenes/office.toml --res 128x96 --tile-w 8 --tile-h 8 \
	    --trav-subunits 4 --out build/bench --name threads_standard.json
	$(SAARCOR) bench threads --scene scenes/office.toml --res 128x96 --tile-w 8 --tile-h 8 \
	    --trav-subunits 4 --trav-sync false --out build/bench --name threads_standard_async.json
	$(SAARCOR) bench stress --out build/bench
	$(SAARCOR) bench chip --res 256x192 --out build/bench $(EYE_ONLY_FLAG)
	$(SAARCOR) bench chip --scene scenes/cornell.toml --res 8x8 --seeds 1000 $(CHIP_SMALL) \
	    --out build/bench $(EYE_ONLY_FLAG)
	$(SAARCOR) bench chip --scene scenes/cornell.toml --res 8x8 --seeds 1000 $(CHIP_SMALL) \
	    --rgs-fp-adders 3 --rgs-fp-muls 4 --out build/bench $(EYE_ONLY_FLAG)
	$(SAARCOR) bench chip --scene scenes/cornell.toml --res 8x8 --seeds 1000 $(CHIP_SMALL) \
	    --rgs-fp-adders 3 --rgs-fp-muls 4 --rgs-fp-pool 1 --out build/bench $(EYE_ONLY_FLAG)
	$(SAARCOR) bench chip --res 64x48 --seeds 16 --out build/bench $(EYE_ONLY_FLAG)
	$(SAARCOR) bench resources --yosys --json build/bench/resources.json
	$(SAARCOR) bench skipping --scene scenes/office.toml --res 128x96 --rtl-cycles --second-run
	$(SAARCOR) bench skipping --scene scenes/cornell.toml --res 128x96 --rtl-cycles
	$(SAARCOR) bench skipping --scene scenes/game.toml --res 128x96 --elab
	$(SAARCOR) bench ladder --out build/bench
	$(SAARCOR) bench simspeed --fresh --profile --quiet --out build/bench
	$(PY) -m pytest -q -m slow

clean:
	rm -rf build

## make render SCENE=scenes/office.toml RES=1024x768: the golden model alone -> build/render/
##   (image.png, stats.json, rays.npz, hits.npz; `saarcor render --help` for every option)
RENDER_OUT ?= build/render
render: setup
	$(SAARCOR) render --scene $(SCENE) --res $(RES) --out $(RENDER_OUT)

## make verilog TOP=rtc CONFIG="--threads 4 --trav-cache-kb 4": build/verilog/$(TOP).v
##   (TOP: any of `saarcor verilog --list`; CONFIG: any Config field as --option)
TOP    ?= rtc
CONFIG ?=
verilog: setup
	$(SAARCOR) verilog --top $(TOP) $(CONFIG)

## make fpga: synth + place & route of the one-RTC FPGA configuration on an ECP5-85k
##   (YoWASP Yosys + nextpnr: Yosys 4-5 min + placement 6-7 min + routing 23-47 min, or a stall; not in CI) -> build/fpga/report.json, README.md
##   8 threads of 4x4-ray packets, deep FP pipelines, the fast_clock registers, delays in LUT-RAM,
##   8-entry cache queues, 24-bit addresses, router1. Whether a placement routes depends on the seed
##   (docs/fpga.md): FPGA_SEEDS tries seeds in turn, stopping a router1 that gains < 2 % of the arcs
##   in 600 s; FPGA_DEEP= for the default timing
FPGA_TOP    ?= rtc
FPGA_DEEP   ?= --fp-add-latency 8 --fp-mul-latency 6 --fp-div-latency 29 --fp-cmp-latency 3 --fast-clock 1 --delay-ram 4 --router router1
FPGA_CONFIG ?= --threads 8 --tile-w 4 --tile-h 4 --trav-subunits 2 --trav-cache-kb 4 --list-cache-kb 4 --int-cache-kb 8 --cache-queue 8 --addr-bits 24 $(FPGA_DEEP)
FPGA_SEEDS  ?= --seed 1 2 3 4 --stall-s 600
fpga: setup
	$(VENV)/bin/pip install -q -e ".[fpga]"
	$(SAARCOR) fpga --top $(FPGA_TOP) $(FPGA_CONFIG) $(FPGA_SEEDS)

.PHONY: render verilog fpga

## make sweep SPEC=scenes/sweeps/rtcs.toml: a design-space sweep on Dask (configurations x scenes
##   x resolutions, every point cached) -> build/sweep/<name>/results.csv (docs/sweep.md)
##   SWEEP_ARGS="--workers 2 --scheduler tcp://host:8786 --max-cycles N"
SPEC       ?= scenes/sweeps/rtcs.toml
SWEEP_ARGS ?=
sweep: setup
	$(SAARCOR) sweep $(SPEC) $(SWEEP_ARGS)

.PHONY: sweep

## make results: docs/results.md and docs/img/results_*.png, the paper's Section 5 tables beside
##   ours, from the sweeps of scenes/sweeps/results/plan.toml (every point kept in
##   scenes/sweeps/results/cache; the chip's Verilator binaries are built once per configuration).
##   The chip frames are the paper's 1024x768 on the paper preset, about half an hour each here,
##   so the whole plan is a cluster's job (docs/sweep.md). RESULTS_ARGS="--cached" writes the
##   page from the kept points alone; "--cluster slurm --workers 32" runs the rest on SLURM
RESULTS_ARGS ?=
results: setup
	nice -n 10 $(SAARCOR) results $(RESULTS_ARGS)

.PHONY: results
