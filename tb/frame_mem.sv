// The large memories of tb/frame.py's RTCFrame (Verilator builds only), in Verilog because
// Amaranth writes every bit of a lib.memory.Memory's initial contents into its output (about
// a minute per 2^17 x 64 bits): these start at zero and are written through the load port.
//
// Same behaviour as amaranth.lib.memory.Memory with one write port (granularity GRAN) and one
// read port: SYNC_READ=1 is read_port() (registered data, enable, not transparent: a read of
// the address being written returns the old word), SYNC_READ=0 is read_port(domain="comb").
module frame_mem #(
    parameter ABITS = 17,
    parameter WIDTH = 64,
    parameter GRAN = 64,
    parameter SYNC_READ = 1
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
