// C++ main for the Verilator build of tb/harness/frame.py's RTCFrame (driven by tb/harness/verilator.py).
//
//   Vframe IN OUT [--max-cycles N] [--progress N] [--trace FILE] [--trace-from C]
//   [--samples FILE --sample-every N] [--ray-bit B] [--res-ports K]
//   (FILE: FST or VCD, as built; C: first run cycle written to it, default 0 = load included)
// SAMPLES (little-endian): "RTCSMP1\0", u32 ctr_words, u32 0, then every N run cycles (and
//   once at the end) a row: u64 cycle, u64 results so far, ctr_words x u32 counters.
//
// IN (little-endian): "RTCIN01\0", u64 blocks, then per block: u32 sel, u32 addr, u64 count,
//   count x u64 words (for ld_addr = addr, addr + 1, ...).
// The memory image (sel 0) goes into the design's preloading memories (tb/harness/frame_mem.sv,
// PRELOAD=1) at time 0 through frame_mem_preload_words/word below, so it costs no clock
// cycles; a design without one takes it through the load port like the other blocks.
// Holds reset for 4 cycles, loads the other blocks (one word per cycle), pulses start, then
// clocks until `finished` or N cycles after start (exit 2, naming the limit). Every result
// transfer (res_valid) is recorded; with --res-ports K (default 1) res_data holds K results side
// by side and bit i of res_valid says the i-th is one (recorded in port order).
// OUT (little-endian): "RTCOUT1\0", u32 status (0 finished, 2 cycle limit), u32 res_words
//   (one result's), u32 ctr_words, u32 0, u64 cycles (RTC cycles since start), u64 results,
//   u64 load cycles,
//   f64 CPU seconds of the run loop, f64 CPU seconds of the load, then results x res_words u32,
//   ctr_words u32 counters.
// stderr: "progress <cycles> <results> <rays>" every --progress cycles (default 65536), errors;
//   <rays>: the results whose bit B is 0 (--ray-bit B: the chip's records of rays, not of
//   pixels), else <results> again.
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <memory>
#include <string>
#include <vector>

#include "Vframe.h"
#include "Vframe__Dpi.h"
#include "verilated.h"
#if VM_TRACE_FST
#include "verilated_fst_c.h"
typedef VerilatedFstC Trace;
#elif VM_TRACE
#include "verilated_vcd_c.h"
typedef VerilatedVcdC Trace;
#endif

static void die(const char* what, const std::string& detail) {
    std::fprintf(stderr, "error: %s: %s\n", what, detail.c_str());
    std::exit(1);
}

struct Sim {
    VerilatedContext* ctx;
    Vframe* top;
#if VM_TRACE
    Trace* tfp = nullptr;
#endif
    uint64_t time = 0;
    bool tracing = true;       // false until --trace-from's cycle

    void dump() {
#if VM_TRACE
        if (tfp && tracing) tfp->dump(time);
#endif
        time++;
    }
    // inputs are set before calling; one rising edge
    void tick() {
        top->clk = 0;
        top->eval();
        dump();
        top->clk = 1;
        top->eval();
        dump();
    }
};

// --- the memory image for the preloading memories (tb/harness/frame_mem.sv) -------------------------
struct Block {
    uint32_t sel, addr;
    uint64_t count;
    const uint8_t* data;     // count little-endian u64 words
};
static std::vector<Block> g_image;   // the sel-0 blocks, sorted by address, not overlapping
static size_t g_cursor = 0;          // the block the last word came from (reads go upwards)
static int g_preloads = 0;           // memories that took the image

long long frame_mem_preload_words() {
    g_preloads++;
    g_cursor = 0;
    return g_image.empty() ? 0 : (long long)(g_image.back().addr + g_image.back().count);
}

long long frame_mem_preload_word(long long k) {
    const uint64_t a = (uint64_t)k;
    if (g_cursor >= g_image.size() || a < g_image[g_cursor].addr) g_cursor = 0;
    while (g_cursor < g_image.size() && a >= g_image[g_cursor].addr + g_image[g_cursor].count)
        g_cursor++;
    if (g_cursor == g_image.size() || a < g_image[g_cursor].addr) return 0;   // a gap
    uint64_t v;
    std::memcpy(&v, g_image[g_cursor].data + 8 * (a - g_image[g_cursor].addr), 8);
    return (long long)v;
}

template <typename W>
static void put_wide(std::vector<uint32_t>& out, const W& w, size_t words) {
    for (size_t i = 0; i < words; i++) out.push_back(w[i]);
}

int main(int argc, char** argv) {
    if (argc < 3) {
        std::fprintf(stderr, "usage: %s IN OUT [--max-cycles N] [--progress N] [--trace F.fst] "
                     "[--trace-from CYCLE]\n", argv[0]);
        return 1;
    }
    std::string in_path = argv[1], out_path = argv[2], trace_path;
    uint64_t max_cycles = 100000000ull, progress = 65536, trace_from = 0, sample_every = 0;
    long long ray_bit = -1;
    long long res_ports = 1;
    std::string samples_path;
    for (int i = 3; i < argc; i++) {
        std::string a = argv[i];
        if (i + 1 >= argc) die("arguments", a + " needs a value");
        if (a == "--max-cycles") max_cycles = std::strtoull(argv[++i], nullptr, 10);
        else if (a == "--progress") progress = std::strtoull(argv[++i], nullptr, 10);
        else if (a == "--ray-bit") ray_bit = std::strtoll(argv[++i], nullptr, 10);
        else if (a == "--res-ports") res_ports = std::strtoll(argv[++i], nullptr, 10);
        else if (a == "--trace") trace_path = argv[++i];
        else if (a == "--trace-from") trace_from = std::strtoull(argv[++i], nullptr, 10);
        else if (a == "--samples") samples_path = argv[++i];
        else if (a == "--sample-every") sample_every = std::strtoull(argv[++i], nullptr, 10);
        else die("arguments", "unknown option " + a);
    }
    if (progress == 0) progress = ~0ull;

    // --- read the whole input file ----------------------------------------------------------
    FILE* f = std::fopen(in_path.c_str(), "rb");
    if (!f) die(in_path.c_str(), "cannot open the input file");
    std::vector<uint8_t> buf;
    {
        uint8_t tmp[1 << 16];
        size_t n;
        while ((n = std::fread(tmp, 1, sizeof tmp, f)) > 0) buf.insert(buf.end(), tmp, tmp + n);
        std::fclose(f);
    }
    size_t pos = 0;
    auto need = [&](size_t n, const char* what) {
        if (pos + n > buf.size())
            die(in_path.c_str(), std::string("truncated input file (") + what + " at byte " +
                                     std::to_string(pos) + " of " + std::to_string(buf.size()) +
                                     "); write it with tb.harness.verilator.write_input");
    };
    auto u32 = [&]() { uint32_t v; std::memcpy(&v, &buf[pos], 4); pos += 4; return v; };
    auto u64 = [&]() { uint64_t v; std::memcpy(&v, &buf[pos], 8); pos += 8; return v; };
    need(16, "header");
    if (std::memcmp(&buf[0], "RTCIN01\0", 8) != 0)
        die(in_path.c_str(), "not an RTCFrame input file (magic is not RTCIN01)");
    pos = 8;
    uint64_t blocks = u64();
    std::vector<Block> all;
    for (uint64_t b = 0; b < blocks; b++) {
        need(16, "block header");
        Block k;
        k.sel = u32();
        k.addr = u32();
        k.count = u64();
        if (k.count > (buf.size() - pos) / 8) need(k.count * 8, "block data");
        k.data = &buf[pos];
        pos += 8 * k.count;
        all.push_back(k);
        if (k.sel == 0) g_image.push_back(k);
    }
    std::sort(g_image.begin(), g_image.end(),
              [](const Block& x, const Block& y) { return x.addr < y.addr; });
    for (size_t i = 1; i < g_image.size(); i++)
        if (g_image[i - 1].addr + g_image[i - 1].count > g_image[i].addr)
            die(in_path.c_str(), "memory image blocks overlap at word " +
                                     std::to_string(g_image[i].addr));

    // --- model ------------------------------------------------------------------------------
    Sim s;
    s.ctx = new VerilatedContext;
    s.ctx->commandArgs(1, argv);
    s.top = new Vframe{s.ctx};
#if VM_TRACE
    if (!trace_path.empty()) {
        s.ctx->traceEverOn(true);
        s.tfp = new Trace;
        s.top->trace(s.tfp, 99);
        s.tfp->open(trace_path.c_str());
    }
#else
    if (!trace_path.empty())
        die("--trace", "this binary was built without tracing; build with trace=True "
                       "(python -m tb.harness.verilator --trace FILE)");
#endif
    Vframe* top = s.top;
    s.tracing = trace_from == 0;
    top->ld_valid = 0;
    top->start = 0;
    top->rst = 1;
    std::clock_t c0 = std::clock();
    for (int i = 0; i < 4; i++) s.tick();     // the first evaluation preloads the image
    top->rst = 0;
    const uint64_t cap_mem = top->cap_mem_words, cap_rays = top->cap_ray_slots;

    uint64_t load_cycles = 0;
    for (uint64_t b = 0; b < all.size(); b++) {
        const uint32_t sel = all[b].sel, addr = all[b].addr;
        const uint64_t count = all[b].count;
        pos = all[b].data - buf.data();
        uint64_t cap = sel == 0 ? cap_mem : sel == 1 ? cap_rays * 8 : sel == 2 ? 256 : 0;
        if (cap == 0) die(in_path.c_str(), "block with unknown target " + std::to_string(sel));
        if ((uint64_t)addr + count > cap)
            die(in_path.c_str(),
                "block " + std::to_string(b) + " (target " + std::to_string(sel) + ") writes words " +
                    std::to_string(addr) + ".." + std::to_string(addr + count) +
                    ", the design has " + std::to_string(cap) +
                    " (memory words / ray slots x 8 / constants): rebuild with larger mem_words / "
                    "ray_slots");
        if (sel == 0 && g_preloads) continue;    // preloaded
        top->ld_sel = sel;
        top->ld_valid = 1;
        for (uint64_t i = 0; i < count; i++) {
            top->ld_addr = addr + (uint32_t)i;
            top->ld_data = u64();
            s.tick();
            load_cycles++;
        }
        top->ld_valid = 0;
    }
    double load_s = double(std::clock() - c0) / CLOCKS_PER_SEC;

    top->start = 1;
    s.tick();
    top->start = 0;

    const size_t all_res_words = sizeof(top->res_data) / sizeof(top->res_data[0]);
    if (res_ports < 1 || res_ports > 32 || all_res_words % res_ports)
        die("--res-ports", "must divide res_data into whole 32-bit results (1..32 ports)");
    const size_t res_words = all_res_words / res_ports;
    const size_t ctr_words = sizeof(top->counters) / sizeof(top->counters[0]);
    FILE* smp = nullptr;
    std::vector<uint32_t> row;
    auto sample = [&](uint64_t cyc, uint64_t res) {
        if (!smp) return;
        uint64_t head[2] = {cyc, res};
        row.clear();
        put_wide(row, top->counters, ctr_words);
        std::fwrite(head, 8, 2, smp);
        std::fwrite(row.data(), 4, row.size(), smp);
    };
    if (!samples_path.empty()) {
        if (sample_every == 0) die("--samples", "needs --sample-every N (N >= 1)");
        smp = std::fopen(samples_path.c_str(), "wb");
        if (!smp) die(samples_path.c_str(), "cannot create the samples file");
        uint32_t h[2] = {(uint32_t)ctr_words, 0};
        std::fwrite("RTCSMP1\0", 1, 8, smp);
        std::fwrite(h, 4, 2, smp);
    }
    std::vector<uint32_t> results;
    uint64_t n_results = 0, n_rays = 0, cycles = 0, next_progress = progress;
    uint32_t status = 0;
    c0 = std::clock();
    while (true) {
        top->clk = 0;
        top->eval();
        if (cycles == trace_from) s.tracing = true;
        if (top->finished) break;
        if (cycles >= max_cycles) {
            status = 2;
            break;
        }
        const uint32_t res_valid = top->res_valid;
        for (long long port = 0; port < res_ports; port++) {
            if (!((res_valid >> port) & 1u)) continue;
            put_wide(results, &top->res_data[port * res_words], res_words);
            n_results++;
            if (ray_bit >= 0) {    // a ray's result, not another record (a pixel's colour)
                const uint32_t w = results[results.size() - res_words + ray_bit / 32];
                n_rays += ((w >> (ray_bit % 32)) & 1u) == 0;
            }
        }
        s.dump();
        top->clk = 1;
        top->eval();
        s.dump();
        cycles++;
        if (smp && cycles % sample_every == 0) sample(cycles, n_results);
        if (cycles >= next_progress) {
            std::fprintf(stderr, "progress %llu %llu %llu\n", (unsigned long long)cycles,
                         (unsigned long long)n_results,
                         (unsigned long long)(ray_bit >= 0 ? n_rays : n_results));
            std::fflush(stderr);
            next_progress += progress;
        }
    }
    double run_s = double(std::clock() - c0) / CLOCKS_PER_SEC;
    if (smp) {
        sample(cycles, n_results);
        std::fclose(smp);
    }
    std::fprintf(stderr, "progress %llu %llu %llu\n", (unsigned long long)cycles,
                 (unsigned long long)n_results,
                 (unsigned long long)(ray_bit >= 0 ? n_rays : n_results));
    if (status == 2)
        std::fprintf(stderr,
                     "error: cycle limit: %llu results after --max-cycles %llu cycles (deadlock, "
                     "or raise the limit)\n",
                     (unsigned long long)n_results, (unsigned long long)max_cycles);

    // --- write the output file --------------------------------------------------------------
    FILE* o = std::fopen(out_path.c_str(), "wb");
    if (!o) die(out_path.c_str(), "cannot create the output file");
    uint32_t hdr[4] = {status, (uint32_t)res_words, (uint32_t)ctr_words, 0};
    uint64_t rtc_cycles = top->cycles;
    uint64_t nums[3] = {rtc_cycles, n_results, load_cycles};
    double secs[2] = {run_s, load_s};
    std::vector<uint32_t> ctrs;
    put_wide(ctrs, top->counters, ctr_words);
    bool ok = std::fwrite("RTCOUT1\0", 1, 8, o) == 8 && std::fwrite(hdr, 4, 4, o) == 4 &&
              std::fwrite(nums, 8, 3, o) == 3 && std::fwrite(secs, 8, 2, o) == 2 &&
              std::fwrite(results.data(), 4, results.size(), o) == results.size() &&
              std::fwrite(ctrs.data(), 4, ctrs.size(), o) == ctrs.size();
    ok = std::fclose(o) == 0 && ok;
    if (!ok) die(out_path.c_str(), "write failed (disk full?)");
#if VM_TRACE
    if (s.tfp) s.tfp->close();
#endif
    top->final();
    delete top;
    delete s.ctx;
    return status;
}
