#!/usr/bin/env python3
# Bytes per band (all levels) of a classic-TIFF, planar-separate part: the sum of
# each band's TileByteCounts over every IFD.  python3 bench/bandsizes.py PART.tif
import struct, sys
d = open(sys.argv[1], 'rb').read()
assert d[:2] == b'II'
big = struct.unpack('<H', d[2:4])[0] == 43
assert not big
off = struct.unpack('<I', d[4:8])[0]
tot = {}
sizes = {1:1,2:1,3:2,4:4,16:8}
while off:
    n = struct.unpack('<H', d[off:off+2])[0]
    tags = {}
    for i in range(n):
        t, ty, c, v = struct.unpack('<HHII', d[off+2+12*i: off+14+12*i])
        tags[t] = (ty, c, v)
    ty, c, v = tags[325]
    sz = sizes[ty]
    vals = struct.unpack('<%d%s' % (c, 'I' if sz == 4 else 'H'), d[v:v+c*sz]) if c*sz > 4 else (v,)
    spp = tags[277][2]
    per = c // spp
    for b in range(spp):
        tot[b] = tot.get(b, 0) + sum(vals[b*per:(b+1)*per])
    off = struct.unpack('<I', d[off+2+12*n: off+6+12*n])[0]
print(' '.join('%d:%d' % (b+1, v) for b, v in sorted(tot.items())), 'total', sum(tot.values()))
