// The memory of tb/harness/chip_sdram.py's ChipOnSDRAM: 2^ABITS words of WIDTH bits, read combinationally
// (as tb/frame_mem.v with SYNC_READ=0), filled at time 0 from the file named by the plusarg
// +image=<file> ($readmemh: one word a line, in hex), so a bench needs no cycles to load a
// scene. Words the file does not give stay X (nothing reads them).
module image_mem #(
    parameter ABITS = 17,
    parameter WIDTH = 64
) (
    input  wire [ABITS-1:0] r_addr,
    output wire [WIDTH-1:0] r_data
);
    reg [WIDTH-1:0] mem [0:(1 << ABITS) - 1];
    reg [8 * 1024 - 1:0] file;
    initial
        if ($value$plusargs("image=%s", file))
            $readmemh(file, mem);
    assign r_data = mem[r_addr];
endmodule
