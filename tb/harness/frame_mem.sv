// The large memories of tb/harness/frame.py's RTCFrame and tb/harness/chip_frame.py's ChipFrame (Verilator
// builds only), in (System)Verilog because Amaranth writes every bit of a lib.memory.Memory's
// initial contents into its output (about a minute per 2^17 x 64 bits). They start at zero and
// are written through the load port; with PRELOAD=1 (64-bit words only) they also take the
// memory image from tb/harness/verilator_main.cpp at time 0, through two DPI-C functions, so a large
// scene's image does not cost one clock cycle of the whole design per word.
//
// Same behaviour as amaranth.lib.memory.Memory with one write port (granularity GRAN) and one
// read port: SYNC_READ=1 is read_port() (registered data, enable, not transparent: a read of
// the address being written returns the old word), SYNC_READ=0 is read_port(domain="comb").
module frame_mem #(
    parameter ABITS = 17,
    parameter WIDTH = 64,
    parameter GRAN = 64,
    parameter SYNC_READ = 1,
    parameter PRELOAD = 0
) (
    input  wire                    clk,
    input  wire [ABITS-1:0]        r_addr,
    input  wire                    r_en,
    output wire [WIDTH-1:0]        r_data,
    input  wire [ABITS-1:0]        w_addr,
    input  wire [WIDTH/GRAN-1:0]   w_en,
    input  wire [WIDTH-1:0]        w_data
);
    reg [WIDTH-1:0] mem [0:(1 << ABITS) - 1];
    integer i;
    // the image's length in words and its word k (tb/harness/verilator_main.cpp)
    import "DPI-C" function longint frame_mem_preload_words();
    import "DPI-C" function longint frame_mem_preload_word(input longint k);
    generate
        if (PRELOAD) begin : g_preload
            initial begin : load
                longint k, n;
                n = frame_mem_preload_words();
                for (k = 0; k < n && k < (64'd1 << ABITS); k = k + 1)
                    mem[k[ABITS-1:0]] = frame_mem_preload_word(k);
            end
        end
    endgenerate
    always @(posedge clk)
        for (i = 0; i < WIDTH / GRAN; i = i + 1)
            if (w_en[i]) mem[w_addr][i * GRAN +: GRAN] <= w_data[i * GRAN +: GRAN];
    generate
        if (SYNC_READ) begin : g_sync
            reg [WIDTH-1:0] data = 0;
            always @(posedge clk)
                if (r_en) data <= mem[r_addr];
            assign r_data = data;
        end else begin : g_comb
            assign r_data = mem[r_addr];
        end
    endgenerate
endmodule
