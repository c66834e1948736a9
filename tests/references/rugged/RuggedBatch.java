// RuggedBatch: drives Orekit Rugged's Duvenhage algorithm over a regular
// geodetic height grid for a batch of rays, for the planet-intersect tests
// and benchmark (an independent reference; see bridge.py next to this file).
//
// Compiled at run time by bridge.py with javac against the jars that the
// PyPI package orekit-jpype bundles, into a cache folder outside the repo.
//
// Grid seen by Rugged (all angles in radians, south-up):
//   node (I, J) at latitude latS + I*dlat, longitude lonW + J*dlon;
//   I in [0, nrows), J in [0, ncols) are the DSM's pixel centres, with the
//   DSM's height; every other node of the lattice (outside the DSM) has the
//   height `fill`. With period > 0 (a whole number of columns makes one
//   turn: period*dlon = 2 pi) the lattice is periodic in longitude: node J is
//   column J mod period, a DSM column when that is below ncols (period ==
//   ncols: a global grid).
// Tiles: R x C nodes, tile (ti, tj) holds nodes I0 .. I0+R-1 and
//   J0 .. J0+C-1 with I0 = ti*(R-1) - margin, J0 = tj*(C-1) - margin, so that
//   neighbouring tiles share one row / column (Rugged's overlapping tiles).
//   A tile is built around the longitude Rugged asks for, which may lie
//   outside [-pi, pi). Without a period, the copy of the DSM nearest to it
//   (shifted by a whole number of turns) is used.
import org.hipparchus.geometry.euclidean.threed.Vector3D;
import org.orekit.frames.Frame;
import org.orekit.frames.Transform;
import org.orekit.rugged.intersection.duvenhage.DuvenhageAlgorithm;
import org.orekit.rugged.raster.TileUpdater;
import org.orekit.rugged.raster.UpdatableTile;
import org.orekit.rugged.utils.ExtendedEllipsoid;
import org.orekit.rugged.utils.NormalizedGeodeticPoint;

public final class RuggedBatch {

    /** Status: Rugged returned a refined intersection. */
    public static final int HIT = 0;
    /** Status: intersection() found a point but refineIntersection() returned null. */
    public static final int REFINE_NULL = 1;
    /** Status: Rugged threw an exception (message kept per ray). */
    public static final int ERROR = 2;
    /** Values per ray in the output array. */
    public static final int NOUT = 10;

    private final ExtendedEllipsoid ellipsoid;
    private final DuvenhageAlgorithm algorithm;
    private final GridUpdater updater;
    private String[] messages = new String[0];

    /** Tile updater serving the lattice described at the top of this file. */
    static final class GridUpdater implements TileUpdater {
        final double[] h;  // south-up, row-major nrows x ncols
        final int nrows, ncols, rows, cols, margin, period;
        final double latS, lonW, dlat, dlon, fill;
        long tilesBuilt = 0;

        GridUpdater(double[] h, int nrows, int ncols, double latS, double lonW,
                    double dlat, double dlon, double fill, int rows, int cols,
                    int margin, int period) {
            this.h = h; this.nrows = nrows; this.ncols = ncols;
            this.latS = latS; this.lonW = lonW; this.dlat = dlat; this.dlon = dlon;
            this.fill = fill; this.rows = rows; this.cols = cols;
            this.margin = margin; this.period = period;
        }

        /** First lattice index of the tile holding coordinate x (rad) with
         *  interpolation neighbours, tested with SimpleTile's own formula. */
        private static long firstIndex(double x, double base, double step, int n, int margin) {
            long t = (long) Math.floor(((x - base) / step + margin) / (n - 1));
            for (int k = 0; k < 4; k++) {  // bounded: rounding moves at most one tile
                long i0 = t * (n - 1) - margin;
                double min = base + i0 * step;
                double idx = Math.floor((x - min) / step);
                if (idx < 0) { t--; } else if (idx > n - 2) { t++; } else { return i0; }
            }
            throw new IllegalStateException("no tile holds coordinate " + x + " rad");
        }

        @Override
        public void updateTile(double latitude, double longitude, UpdatableTile tile) {
            if (Double.isNaN(latitude) || Double.isNaN(longitude)) {
                throw new IllegalArgumentException("tile requested at NaN latitude/longitude");
            }
            double base = lonW;
            if (period <= 0) {  // the copy of the DSM nearest to the requested longitude
                double centre = lonW + 0.5 * (ncols - 1) * dlon;
                base += 2 * Math.PI * Math.rint((longitude - centre) / (2 * Math.PI));
            }
            long i0 = firstIndex(latitude, latS, dlat, rows, margin);
            long j0 = firstIndex(longitude, base, dlon, cols, margin);
            tile.setGeometry(latS + i0 * dlat, base + j0 * dlon, dlat, dlon, rows, cols);
            for (int r = 0; r < rows; r++) {
                long ii = i0 + r;
                boolean rowIn = ii >= 0 && ii < nrows;
                for (int c = 0; c < cols; c++) {
                    long jj = j0 + c;
                    if (period > 0) { jj = Math.floorMod(jj, (long) period); }
                    boolean in = rowIn && jj >= 0 && jj < ncols;
                    tile.setElevation(r, c, in ? h[(int) (ii * ncols + jj)] : fill);
                }
            }
            tilesBuilt++;
        }
    }

    public RuggedBatch(double[] heights, int nrows, int ncols, double latS, double lonW,
                       double dlat, double dlon, double fill, int rows, int cols, int margin,
                       int period, double a, double f, int maxCachedTiles) {
        if (heights.length != (long) nrows * ncols) {
            throw new IllegalArgumentException("heights has " + heights.length
                                               + " values, expected nrows*ncols");
        }
        // Rugged only needs the body frame to tag points: a plain frame under
        // the root (no Orekit data files are read).
        Frame body = new Frame(Frame.getRoot(), Transform.IDENTITY, "planet-intersect body", true);
        this.ellipsoid = new ExtendedEllipsoid(a, f, body);
        this.updater = new GridUpdater(heights, nrows, ncols, latS, lonW, dlat, dlon, fill,
                                       rows, cols, margin, period);
        // overlapping tiles (Rugged's zipper tiles are for seamless DEMs)
        this.algorithm = new DuvenhageAlgorithm(updater, maxCachedTiles, false, true);
    }

    /** Intersect n rays: s and l are 3n (x, y, z per ray, body frame, metres),
     *  out is NOUT*n: status, lat, lon, h (refined; rad, rad, m), x, y, z
     *  (refined, body frame), lat0, lon0, h0 (intersection() before refining). */
    public void intersect(double[] s, double[] l, double[] out) {
        int n = s.length / 3;
        if (l.length != 3 * n || out.length != NOUT * n || s.length != 3 * n) {
            throw new IllegalArgumentException("s, l must be 3n and out NOUT*n long");
        }
        messages = new String[n];
        for (int k = 0; k < n; k++) {
            java.util.Arrays.fill(out, NOUT * k, NOUT * (k + 1), Double.NaN);
            Vector3D p = new Vector3D(s[3 * k], s[3 * k + 1], s[3 * k + 2]);
            Vector3D d = new Vector3D(l[3 * k], l[3 * k + 1], l[3 * k + 2]);
            try {
                NormalizedGeodeticPoint g0 = algorithm.intersection(ellipsoid, p, d);
                out[NOUT * k + 7] = g0.getLatitude();
                out[NOUT * k + 8] = g0.getLongitude();
                out[NOUT * k + 9] = g0.getAltitude();
                NormalizedGeodeticPoint g = algorithm.refineIntersection(ellipsoid, p, d, g0);
                if (g == null) {
                    out[NOUT * k] = REFINE_NULL;
                    continue;
                }
                Vector3D q = ellipsoid.transform(g);
                out[NOUT * k] = HIT;
                out[NOUT * k + 1] = g.getLatitude();
                out[NOUT * k + 2] = g.getLongitude();
                out[NOUT * k + 3] = g.getAltitude();
                out[NOUT * k + 4] = q.getX();
                out[NOUT * k + 5] = q.getY();
                out[NOUT * k + 6] = q.getZ();
            } catch (RuntimeException | StackOverflowError e) {
                out[NOUT * k] = ERROR;
                messages[k] = e.getClass().getSimpleName() + ": " + e.getMessage();
            }
        }
    }

    /** Messages of the rays of the last intersect() call that ended in ERROR (null elsewhere). */
    public String[] getMessages() {
        return messages;
    }

    /** Number of tiles the updater has built so far. */
    public long getTilesBuilt() {
        return updater.tilesBuilt;
    }

    /** Time the batch loop: warmup untimed calls, then repeats timed ones;
     *  returns the wall-clock seconds of each timed call (System.nanoTime). */
    public double[] time(double[] s, double[] l, int warmup, int repeats) {
        double[] out = new double[NOUT * (s.length / 3)];
        for (int i = 0; i < warmup; i++) {
            intersect(s, l, out);
        }
        double[] t = new double[repeats];
        for (int i = 0; i < repeats; i++) {
            long t0 = System.nanoTime();
            intersect(s, l, out);
            t[i] = (System.nanoTime() - t0) * 1e-9;
        }
        return t;
    }
}
