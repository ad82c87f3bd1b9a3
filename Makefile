# SaarCOR in Amaranth — top-level commands. Each target sets up what it needs by itself.
VENV  ?= .venv
PY    := $(VENV)/bin/python
STAMP := $(VENV)/.setup-done
SCENE ?= scenes/cornell.toml
RES   ?= 256x192
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

## make sim: render the default scene (golden model until the RTL chip exists)
sim: setup
	$(PY) -m model render $(SCENE) --res $(RES) --out $(OUT)

## make bench: long sweeps and speed measurements, written to build/bench/
BENCH_SCENE ?= scenes/office.toml
# the golden model's speed against Embree: a real mesh if one is at hand (the README's figures
# use the Stanford dragon), else the procedural terrain
BENCH_MESH  ?= $(firstword $(wildcard $(SAARCOR_MESHES)/dragon.obj ../shared/meshes/dragon.obj))
bench: setup
	mkdir -p build/bench
	$(PY) -m model.bench --out build/bench $(if $(BENCH_MESH),--mesh $(BENCH_MESH))
	$(PY) -m tb.bench_memory --scene $(BENCH_SCENE) --out build/bench
	$(PY) -m tb.bench_threads --out build/bench
	$(PY) -m tb.bench_threads --scene scenes/office.toml --res 128x96 --tile 8x8 --subunits 4 \
	    --out build/bench --name threads_standard.json
	$(PY) -m tb.bench_threads --scene scenes/office.toml --res 128x96 --tile 8x8 --subunits 4 \
	    --mode async --out build/bench --name threads_standard_async.json
	$(PY) -m tb.stress --out build/bench
	$(PY) -m pytest -q -m slow

clean:
	rm -rf build

## make verilog TOP=rtc CONFIG="--threads 4 --trav-cache-kb 4": build/verilog/$(TOP).v
##   (TOP: any of `python -m rtl.export --list`; CONFIG: any Config field as --option)
TOP    ?= rtc
CONFIG ?=
verilog: setup
	$(PY) -m rtl.export --top $(TOP) $(CONFIG)

## make fpga: synth + place & route of the one-RTC FPGA configuration on an ECP5-85k
##   (YoWASP Yosys + nextpnr, an hour or more on 2 cores; not in CI) -> build/fpga/report.json, README.md
##   deep FP pipelines and the fast_clock registers (docs/fpga.md); FPGA_DEEP= for the default timing
FPGA_TOP    ?= rtc
FPGA_DEEP   ?= --fp-add-latency 8 --fp-mul-latency 5 --fp-div-latency 29 --fp-cmp-latency 3 --fast-clock 1
FPGA_CONFIG ?= --threads 4 --trav-subunits 2 --trav-cache-kb 4 --list-cache-kb 4 --int-cache-kb 8 $(FPGA_DEEP)
fpga: setup
	$(VENV)/bin/pip install -q -e ".[fpga]"
	$(PY) -m rtl.fpga --top $(FPGA_TOP) $(FPGA_CONFIG)

.PHONY: verilog fpga
