"""Bandwidth buffer (002 Sec. 2.2, 2.4-2.6, 3.1): per pixel nu, b_p, shading level, variance bound, N_p.

Public:
    ``N_B_DEFAULT``, ``N_B_MAX``, ``NYQUIST_FACTOR``, ``N_P_MIN_DEFAULT``, ``N_P_MAX_PER_BUDGET``, ``BUDGET_MAX``,
    ``ALLOCATION_DEFAULT``, ``LUMINANCE``
    ``make_bandwidth_kernel(kinds, preconvolved)``   the pass's kernel (compiled ahead by the pipeline)
    ``load_kernels(device, relative)``   compile the block-plan and pooling kernels (and the relative bound's)
                                       ahead, outside the pass's time
    ``BandwidthTables`` (Warp struct) / ``make_bandwidth_tables(nu_env, nu_rho, device)``
    ``nu_env_table(nu_env) -> (h, w)``   the environment's nu_a, max-filtered by halves to LIGHT_TABLE_WIDTH columns
    ``env_bandwidth_map(pixels, name, cache=None, signal, progress, source) -> ((H, W) float32 cycles/rad, origin)``;
    ``env_bandwidth_settings(signal) -> dict``, ``ENV_BW_UNRECORDED``: the builder settings its cache entries record
    ``ENV_SIGNALS``, ``ENV_SIGNAL_DEFAULT``, ``env_signal(lum, signal)``, ``check_env_signal(signal)``: what it reads;
    ``env_bandwidth_memory(width, height)``, ``ENV_BW_BYTES_PER_TEXEL``, ``ENV_BW_BYTES_FIXED``: the memory its build
    takes (a warning first where it lacks)
    ``direction_set(n_b, seed) -> (n_b, 3) float32``   stratified points for the n_b directions
    ``interleave_shifts(n_b, side) -> (side^2, 3)``     per-block offsets of the direction set
    ``BandwidthBuffer`` (``.estimator_variance(mis)``, ``.measured_key(mis)``, ``.median_lit_mu()``) /
    ``bandwidth_pass(gb, cam, materials, env_data, tables, n_b, ..., stride, pool_radius, relative)``
    ``SampleAllocation`` / ``allocate_samples(buf, budget, n_min, n_max, allocation, mis, plan)``; ``ALLOCATIONS``
    ``planned_shading(buf, device, key, plan)``   the key of the texels the hierarchy will shade; ``pixel_angle(cam)``
    ``PASS_STRIDE_DEFAULT``, ``POOL_RADIUS_DEFAULT``
    Warp functions ``brdf_nu_rho(nu_rho, m, wi, wo)`` and ``nu_env_at_uv(nu_env, uv)`` (table look-ups)
    Warp functions ``frac3``, ``block_pixel``, ``block_shift`` (the block plan's arithmetic) and ``alike`` (who pools
    with whom), and the kernels ``block_plan_kernel``, ``pool_kernel``, ``relative_bound_kernel`` (what
    ``load_kernels`` compiles)

Three Warp kernels over the G-buffer (002 Sec. 2.6: a block plan, the directions, the pooling), and one that
relates the bound to each pixel's radiance (``relative_bound_kernel``).  For
pixel p (point x, view direction w_o, shading normal n, mean curvature c, distance d' to the camera)
and n_b directions w_i with density pdf_i:

    chi_i    = L_i(w_i) rho(w_i, w_o) (w_i . n)      the integrand of Eq. 1 (lambda_i of Eq. 5)
    nu^i     = |T_{d'} R [0, nu_a^env(w_i)]|          Eq. 4 with a distant light (T_d is then the identity)
    nu       = sum_i (chi_i / pdf_i) nu^i / sum_i (chi_i / pdf_i)                Eq. 5
    b_p      = nu_a max(f_x / W, f_y / H)                                        Eq. 6, cycles/pixel
    sigma2_p = 4 pi^2 E_uniform[(nu_a^env + nu_rho + nu_cos) chi^2]
             = 4 pi^2 / (2 pi n_b) sum_i (nu_a^env,i + nu_rho^i + nu_cos) chi_i^2 / pdf_i
                                                     Eq. 9 (Eq. 10: 2 nu_rho^i + nu_cos)

so that ``V(L_p) <= sigma2_p / N_p`` for uniform sampling.  Eq. 10 (``preconvolved``, 002 Sec. 2.5) is the
bound of an estimator of the pre-filtered light, which the renderer does not run (pre-convolved shading is not built):
it is 0.30 of the uniform-sampling variance of the unfiltered integrand on a Lambert sphere under the procedural sky,
studio.exr or city.exr (nu_rho = 0 leaves NU_COS alone; Eq. 9 held there on every pixel checked), and, taken as the
paper writes it, it exceeds Eq. 9 wherever nu_a^env < nu_rho (the filtered light's band is then the light's, not the
BRDF's): 1.8-2.0 times Eq. 9 under a constant light with GGX alpha 0.2 or color-changing-paint3 (session 77,
per-pixel quadratures).  R (Eq. 3) takes the curvature c from the
G-buffer, cos theta_i = w_i . n, cos theta_x = w_o . n, the BRDF's angular bandwidth nu_rho(w_i, w_o)
from its table (:mod:`precompute.brdf_bandwidth`) and t = 0 (no textures).  Choices where the paper is
silent:

* Directions: one-sample MIS of the BRDF's sampler and the environment's, each picked with probability
  1/2 (pdf_i = (p_brdf + p_env) / 2), from a seeded Hammersley set (:func:`direction_set`).  Sums over
  i are importance-weighted estimates of the integrals the paper writes as sums.  Uniform directions
  (our first version, and what the bound of Sec. 2.4 assumes) miss the lobe of a sharp BRDF and the
  sun of a probe: 16 of them put a chrome sphere's highlights at coarse levels (measured: PSNR stuck at
  32.5 dB whatever the budget) and gave variance rank correlations of 0.1-0.3 against brute force
  (examples/validate_bandwidth.py); MIS directions, shared and pooled as below, reach 0.69-0.96,
  conservative on >= 99.7% of pixels.
* Sharing: the directions are traced once per ``stride x stride`` block whose pixels are all covered
  and alike (:func:`alike`: same material, depths within ``BLOCK_DEPTH_TOL``, normals within
  acos(``BLOCK_NORMAL_COS``)); every pixel of a block at a silhouette or an edge is traced.  Each block
  of a ``side x side`` tile shifts the direction set differently (:func:`interleave_shifts`,
  interleaved sampling; each tile adds its own random offset, :func:`block_shift`), and each pixel
  pools the sums of the alike traced pixels within ``pool_radius`` pixels: about side^2 x n_b
  directions per estimate for the price of n_b per block.  Defaults (2, 2)
  trace about a quarter of the pixels; ``stride=1, pool_radius=0`` is the per-pixel pass.  Measured on the
  gold bunny (512x512, forest.exr, MIS, budget 2, PSNR of the mean MSE over 8 seeds): (stride, pool_radius) =
  (2, 2) 36.4 dB; (1, 0) 34.8; (2, 0) 32.8; (2, 1) 35.5; (2, 4) 34.3; and a hierarchical plan (4 x 4 blocks
  where alike, else 2 x 2, else single pixels), which traces 9,508 pixels instead of 22,843: 35.2 (pool 2),
  33.0 (0), 32.1 (1).  Coarser blocks save less than their size suggests, because a block that is not alike
  traces every one of its pixels: the 17% of the bunny's covered pixels that lie in such 4 x 4 blocks are most of
  what (4, 4) traces (session 37, budgets 4 / 8 / 16, 4 paired seeds, ``/work/bench/s37/stride_sweep.py``).
  (3, 3) traces 16,178 pixels, the pass takes 108 ms instead of 140, and the frame loses 0.56 / 0.54 / 0.45 dB;
  (4, 4) traces 18,511 pixels in 114 ms and loses 0.77 / 0.42 / 0.23 dB; (4, 6) loses 2.8 / 1.8 / 0.8 dB.  No
  frame (pass and hierarchy) got faster by more than 12%.
  The variance bound sigma2 takes the largest of the neighbours' own n_b-direction estimates instead of their pooled
  mean (Sec. 3.1 max-filters the variance): E(chi^2) is heavy-tailed under small bright lights, and the
  max is conservative on more pixels (bunny under studio.exr, examples/validate_bandwidth.py, measured
  before the per-tile offsets: 89% of pixels instead of 85%, rank correlation unchanged).
* The same directions measure the variance of their own one-sample MIS estimate of L_p,
  ``variance_mis`` = E[(chi / pdf)^2] - E[chi / pdf]^2: the spread of the renderer's (MIS) estimator,
  which the Eq. 9 bound, written for uniform sampling, does not follow (below).  And, reweighted, that of
  BRDF sampling alone (the renderer without MIS), ``variance_bis`` = E_pdf[chi^2 / (p_brdf pdf)] - mu^2 =
  E_brdf[(chi / p_brdf)^2] - mu^2: under a small bright light the two differ by orders of magnitude, and N_p
  follows the one the frame is rendered with.  Until session 34 a frame without MIS was allocated by the MIS
  variance; with the cap raised to 256 x budget (below) that gave the chrome sphere's highlights the
  samples that its other pixels, whose fireflies BRDF sampling cannot avoid, needed (13.6x -> 6.4x).
  The renderer's MIS step is not the pass's one-sample estimate Y but two samples, X = g(a) + g(b), g = chi /
  (p_brdf + p_env), a ~ p_brdf, b ~ p_env (:mod:`warpbw.shading`): Var(X) = int chi^2 / (p_brdf + p_env) - a_b^2 -
  a_e^2, a_j = int chi p_j / (p_brdf + p_env), and Var(Y) = 2 Var(X) + (a_b - a_e)^2.  The same directions
  estimate it, ``variance_step`` = E[Y^2] / 2 - a_b^2 - a_e^2 with a_b = E[Y p_brdf / (p_brdf + p_env)] and a_e =
  mu - a_b: against 200 renders of 8 spp per pixel (24 x 24 spheres, Lambert and GGX alpha 0.2 under a constant
  sky, the procedural sky and a 2 x 2-texel sun of 5000 on a sky of 0.5; 4096 directions per pixel) its ratio to
  the brute force has medians 1.00-1.02 (10th-90th percentiles 0.85-1.19), ``variance_mis``'s 2.1-4.5 (1.8-5.4).
  An MIS frame's variance map reads ``variance_step`` over N_p (since session 74: it read ``variance_mis``, 2-4.5x
  the frame's variance and unevenly so), but its "measured" allocation keeps ``variance_mis`` as its key, by
  measurement: allocating by ``variance_step`` moved small spheres by +0.01 to +0.05 dB (128 x 128, every pixel
  shaded, GGX alpha 0.03 under studio.exr, 0.2 under forest.exr, Lambert under studio.exr, budgets 2 and 8, 6
  paired seeds against 4096 spp; -0.04 to +0.01 with the default levels at 256 x 256), and the benchmark's scenes
  (8 paired runs, budgets 0.5-32) by -0.01 to +0.03 dB (gold bunny, ccp3 sphere), -0.03 to +0.00 (acrylic bunny)
  and -0.07 to -0.16 dB at every budget on the chrome sphere (docs/measurements.md, "Session 74").  A likely
  reason, not measured: the step's variance is a difference of large terms (E[Y^2] / 2 - a_b^2 - a_e^2), noisy
  from 16 directions where one sampler carries the integrand, as on a mirror, where the one-sample variance's extra
  (a_b - a_e)^2 keeps its key away from 0.
* chi_i includes the cosine of Eq. 1 (the paper writes chi_i = L_i rho): grazing directions, which
  carry no energy, then do not inflate the bound.  The integrand's bandwidth in Eq. 9 then includes
  the cosine's, ``NU_COS``: without it a Lambert surface under a smooth light (nu_a, nu_rho -> 0) gets
  a bound near 0, below the true variance of uniform sampling (a^2 / 3 for albedo a under a constant
  light, against 4 pi^2 NU_COS (a / pi)^2 / 3 = 0.4 a^2 with it; measured on the bunny under
  studio.exr: conservative on 85% of pixels without it).
* Eq. 9's sum over i is taken as a mean, E(chi^2) estimated from n_b samples, so that sigma2 does
  not grow with n_b (the n_b sweep of Fig. 13 would otherwise change the sample counts); the
  angular bandwidth of the light in Eq. 9 is the light's at x (before reflection), nu_a^env(w_i).
* The light entering Eq. 4 is band-limited by the integrand: ``nu_in = min(nu_a^env, nu_rho + NU_COS)``.
  Fig. 4's B limits only the angular component *after* the curvature shear C_c has copied the full
  light bandwidth c nu_a^env into the spatial one, so a Lambertian sphere (nu_rho = 0) would inherit
  the probe's sharpest detail times its curvature (measured: every pixel at level 0 under forest.exr).
  But the reflected radiance integrates L rho cos over w_i, which keeps only the light's angular
  frequencies that the band of rho cos can bring back to 0 (Eq. 8's convolution, read at angular
  frequency 0): at most nu_rho + NU_COS.  Diffuse irradiance is smooth, as it should be; a sharp lobe
  (nu_rho large) passes the light unchanged, as before.
* Curvature c of Eq. 3 is the G-buffer's: 1 / r on a sphere, and on a mesh the magnitude of the mean
  curvature H = (k1 + k2) / 2 averaged over about two rings (``warpbw.io.mesh.local_curvature``: 8 lazy
  one-ring passes; ``warpbw.mesh_normals.local_curvature`` on the device for dynamic geometry).  The flatland
  paper has one curvature; 002 names "the Gaussian curvature ... in m^-1", whose unit is m^-2, and keeps a
  max-filtered, hence unsigned, curvature mip-map (Sec. 3.1).  Why the magnitude, averaged: on a scanned mesh
  H changes sign from vertex to vertex (32% of the bunny's edges join a convex to a concave vertex;
  neighbouring H correlate at 0.42), so the shading normal turns back and forth at the vertex scale, and a
  pixel sees how fast it turns, not which way.  With the signed H, Eq. 3's two shears partly cancel on every
  concave vertex (a focusing mirror), and that reading is right only for concavities much wider than a pixel.
  Bandwidth rank correlation per pixel (examples/validate_bandwidth.py) on the bunny with gold-metallic-paint
  under studio.exr, with color-changing-paint3 under forest.exr and with gold-metallic-paint under forest.exr:
  - signed H (the default until session 28): 0.351 / 0.302 / 0.221 (512x512: 0.292);
  - |H| per vertex: 0.419 / 0.333 / 0.282;
  - |H| averaged over the mesh, 4 passes: 0.492 / 0.369 / 0.332; 8 passes (the default): 0.516 / 0.383 /
    0.350 (512x512: 0.507);
  - |H| averaged, then given H's sign back: 0.410 / 0.328 / 0.237; the signed H averaged (the bumps cancel):
    0.274 / 0.268 / 0.138 (2 passes);
  - log |H| averaged (a geometric mean): 0.461 / 0.375 / 0.289; the smaller of |H| and its average: 0.436 /
    0.351 / 0.286;
  - |H| averaged in screen space over alike pixels within 2 or 4 px: 0.418 / 0.329 / 0.257 and 0.449 / 0.352 /
    0.276;
  - per vertex, the principal curvature of larger magnitude k_max = H + sgn(H) sqrt(H^2 - K) (K from the
    angle deficit) and the RMS sqrt(2 H^2 - K): 0.421 and 0.413 on the first scene (with H's sign); on the
    gold bunny benchmark k_max shaded 45% of the pixels instead of 23% and lost 4.6 dB at budget 1;
  - curvature in screen space from the G-buffer (dn . dP / |dP|^2 along each image axis, between neighbours
    of the same material within 5% in depth; 1 / r on a unit sphere within 2e-6): 0.307 (mean of the two
    axes, 1 px), 0.274 (2 px), 0.330 (the axis of larger magnitude, 2 px).
  The cost is on the benchmark's acrylic bunny (MIS, one run each, back to back, session 27): it shades 75% of
  its pixels instead of 65% and loses about 0.9 dB at every budget (0.99x against 1.14x), while the gold bunny
  gains (3.14x against 2.97x; budget 4, 37.96 against 36.84 dB); the full benchmark of session 28 (docs/measurements.md)
  reads 3.48x and 1.05x with MIS (3.69x and 0.99x over 8 runs, session 29).  The acrylic bunny is
  noise-limited: each extra pixel shaded at level 0 takes samples from the others.  Keeping H's sign instead
  shaded fewer pixels there (64%; 1.19x against 1.06x in one run) but ranks 0.410 on the first scene.
* Luminance (``LUMINANCE``, Rec. 709) reduces the RGB integrand L rho cos to the scalar chi: the luminance of the
  product, so that mu estimates L_p's luminance.  Until session 73 it was the product of the luminances of L and rho,
  1.3x L_p's for a red Lambert under a blue sky, and a red surface under a green sky read as lit.
* L_i is the environment's own radiance at w_i (the renderer's bilinear look-up, ``env_radiance_uv``), and
  nu_a^env comes from a reduced lat-long table (:func:`nu_env_table`: nu_a max-filtered by halves down to
  ``LIGHT_TABLE_WIDTH`` columns), one nearest fetch per direction.  Until session 34 L_i came from a
  box-filtered table of the same size: a light smaller than a reduced texel was spread over the texel, so a
  BRDF-sampled direction beside it read the light's mean, and one the light sampler drew inside it a
  fraction of its radiance.  Under a 2 x 2-texel sun in a 1024 x 512 map the pass's variance on a Lambert
  sphere reached 1,333 times the most the renderer's brute-force noise allows (tests/test_bandwidth.py).
  With the map's own radiance the pass's one-sample MIS variance follows the renderer's per-pixel variance
  more closely: rank correlation over the shaded pixels 0.46 -> 0.65 on the blue-acrylic bunny under
  studio.exr (the benchmark's), 0.914 -> 0.931 on the ccp3 sphere, 0.922 -> 0.925 on the gold bunny.  The
  acrylic bunny gains 0.7-1.0 dB at budgets 8-32 (equal-quality speed-up 0.92x -> 1.13x, 3 runs back to
  back); the chrome sphere's PSNR moves by under 0.01 dB, the gold bunny's within its noise (8 paired runs,
  budgets 1-8: -0.30, -0.02, -0.50 and +0.36 dB, each within one standard error of the difference).  The cost is the
  cache: on the gold bunny the pass takes 104 ms against 94 (median of 15), since the map (6 MB at
  1024 x 512) misses where the reduced table (256 KB) did not; a nearest fetch in the map costs the same
  as the bilinear one (103 ms), and the bilinear one is what the renderer integrates.
  Measured, not adopted (session 28): nu_a max-filtered further over 4, 8 or 16 texels of that table (0.1 to
  0.4 rad, a GGX alpha = 0.2 lobe's reach), so that a direction inside a smooth light would also see its
  edges.  On the GGX sphere of examples/validate_bandwidth.py, whose prediction is lowest in the highlight
  where the reference reads some detail, the per-pixel figure falls from 0.491 to 0.489, 0.487 and 0.479.
* The probe's nu_a is Eq. 7 applied to log(1 + L / mean L) (``ENV_SIGNAL_DEFAULT``, "log"; :func:`env_signal`).
  ``env_signal="radiance"`` (``--env-signal radiance``) applies it to the luminance, as 002 does.  Why the log:
  Eq. 7 reads a texel's bandwidth off the wavelets that reach it, and a sun's coarse wavelets reach tens of
  degrees.  In tests/test_bandwidth.py's probe, a dark edge 34 degrees from a 2 x 2-texel sun 10^4 times the
  sky reads 1.0 cycles/rad on radiance against 6.6 without the sun; on the log it reads 6.1.  A near-mirror
  then up-samples across such edges (docs/measurements.md, "Adaptive shading: where it fails").
  The log leaves the probe linear below its mean and compresses what lies above it.  Once a sun carries most of the
  mean it fails too: at 5 x 10^4 the same edge reads 1.4.
  Measured (session 42; ``/work/bench/s42``).  The mirror of ``examples/mirror_smear.py`` at 128 x 128 under
  city.exr goes from a relative MSE of 0.909 to 0.064 (shaded 19% -> 77%); under studio.exr from 0.0157 to
  0.0044.  examples/validate_bandwidth.py's per-pixel bandwidth rank goes from 0.599 to 0.711 on the ccp3
  sphere under forest.exr (002 Fig. 12's scene), 0.520 -> 0.517 on the bunny and 0.494 -> 0.486 on the GGX
  sphere (both under studio.exr); the variance ranks move by at most 0.01.  On the benchmark
  (``examples/bench_scenes.py``, MIS, 3 paired runs) it shades more pixels, and at equal budget the frames lose
  PSNR: the ccp3 sphere 0.06-1.15 dB (shaded 14.5% -> 21.2%), the gold bunny 0.01-0.35 dB (24.9% -> 28.2%),
  the acrylic bunny 0.01-0.08 dB; the chrome sphere moves by -0.34 to +0.12 dB.  So it was not the default then:
  the benchmark's frames are limited by noise, and every extra pixel shaded takes samples from the others.
  The default since session 58 (``/work/s58``).  Once the wavelet bands were centred on what they describe
  (``precompute.wavelets``), the radiance read the edges of small bright lights slower: the benchmark's chrome
  sphere under studio.exr lost 0.3 dB at budget 0.5 up to 8.9 dB at 32 against the off-centre code (a thin
  light's reflection up-sampled from the dark beside it), and the mirror smeared more under studio.exr at every
  size.  On the centred analysis the log reads, against the off-centre code's radiance (3 paired runs, budgets
  0.5-32): chrome sphere -0.54 to +0.12 dB, gold bunny +1.1 to +1.6, acrylic bunny +0.2 to +1.4, ccp3 sphere
  -0.37 to -0.01; against the centred radiance it costs the ccp3 sphere 0.03-0.29 dB and the acrylic bunny up to
  0.2.  The mirror at 128 x 128 reads 2.9e-3 under city.exr and 2.2e-3 under studio.exr, and the per-pixel
  bandwidth ranks of examples/validate_bandwidth.py 0.815 / 0.489 / 0.542 (ccp3 sphere / gold bunny / GGX sphere;
  0.761 / 0.494 / 0.668 on the radiance).
* The level (Eq. 11) is computed from the Nyquist sampling rate ``NYQUIST_FACTOR * b_p``: Sec. 2.2
  says "the required sampling rates at the image plane are twice the local image-space bandwidth".
  Measured, not adopted (session 31, a scratch patch; gold bunny of examples/bench_scenes.py, MIS, 4 runs): a
  rate that also grows with the pixel's brightness, times sqrt(mu / median mu) where above 1 (mu the pass's
  own estimate of L_p), since the up-sampling's bias there sits on bright ridges
  (docs/measurements.md, "Where the time goes").  It shades 33% of
  the pixels instead of 25% and reads 29.65 / 33.90 / 37.25 / 39.45 dB at budgets 1 / 2 / 4 / 8 against
  33.74 / 36.53 / 38.17 / 38.34; its best speed-up, 3.73x +/- 0.69 (budget 8) against 3.09x +/- 0.18
  (budget 4), is within the noise.  With the factor also below 1 (down to 0.5) the best is 2.90x.
  ``--nyquist 1.5`` on all four benchmark scenes (session 42, 3 runs, same seeds as the default's; PSNR against it
  at budgets 0.5-32): the acrylic bunny gains 0.2-1.0 dB (shaded 74.7% -> 62.8%) and the ccp3 sphere -1.4 to +1.9;
  the gold bunny gains 0.4-3.0 dB at budgets 0.5-2 and loses 0.1-2.3 dB at 4-32.  The chrome sphere collapses,
  losing 5.6-22.5 dB: its highlights need level 0.  The rate that balances the up-sampling's bias against the
  noise of spreading the budget thinner differs from scene to scene, and one factor cannot serve them all.  With
  ``env_signal="log"`` at 1.5 the figures fall between (gold bunny +2.0 to -2.3, ccp3 +0.7 to -1.2, chrome the same
  collapse).

N_p (Sec. 2.4: "keep N_p proportional to" the bound, so that the variance is constant):
``N_p = clamp(ceil(k_p / V), n_min, n_max)`` with k_p = sigma2_p ("variance", the paper's), its square
root ("sqrt"), sigma2_p / L_p^2 ("relative"; L_p^2 + (REL_FLOOR m)^2 with m the frame's median L_p over its
lit pixels, so that it does not see the exposure), 1 ("uniform") or sqrt(variance_mis) ("measured", the default;
sqrt(variance_bis) for a frame without MIS; ``BandwidthBuffer.measured_key``), and the constant V found by bisection so
that the texels the hierarchy will shade (``warpbw.adaptive.plan_hierarchy``'s: those of level L whose min-filtered
level is L, and those the up-sampling cannot fill; each with the max-filtered k of its footprint, Sec. 3.1) spend
``budget`` samples per covered pixel in total.  Why "measured": N_p
proportional to the standard deviation minimises the summed variance sum_p var_p / N_p for a fixed budget
(Neyman allocation), and the standard deviation that matters is the renderer's importance-sampled
estimator's, which the bound does not predict (the paper calls the bound "very conservative").  Measured with
MIS, 256x256 and 512x512, budgets 4 and 16, single frames: +1 to +6 dB over "uniform"; "sqrt" fell between the
two (bunny, budget 4: uniform 32.8, sqrt 35.3, measured 36.4 dB), "variance" 3 dB below "measured" (ccp3, budget 2).
The default cap ``n_max = N_P_MAX_PER_BUDGET x budget`` was 32 x budget until session 34.  On the chrome
sphere of examples/bench_scenes.py (studio.exr, budget 4) that cap held 1,044 of the 5,246 shaded pixels,
the highlights, and 71% of the samples: Neyman's allocation wanted more there.  At 256 x budget it holds
one pixel of the four benchmark scenes at their best budgets (gold bunny, budget 4), and the chrome
sphere's PSNR rises by 4.6-4.9 dB at budgets 1-4 (equal-quality speed-up 12.7x -> 22.7x, 3 runs back to
back), while its relative MSE, which weighs the dark pixels that gave up samples as much as the
highlights, rises by a quarter (5.6e-4 -> 6.9e-4 at budget 1).  The gold bunny, whose cap held 68 pixels,
and the ccp3 sphere (70) move within their noise.
When even ``n_min`` per shaded pixel exceeds the budget (a budget below the shaded fraction), every
shaded pixel gets ``n_min`` and ``SampleAllocation.over_budget`` says so; pixels are never left unshaded.
"""
from __future__ import annotations

import functools
import hashlib
import math
import numbers
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import warp as wp

from precompute.brdf_bandwidth import N_CELLS, N_THETA_I
from warpbw.bandwidth_ops import bw_one_bounce
from warpbw.brdf import MaterialBuffers, MaterialTable, check_sampling_tables, make_brdf_funcs
from warpbw.envmap import EnvMapData, check_env_data, env_pdf_uv, env_radiance_uv, env_sample, env_uv
from warpbw.errors import (FLOAT32_MAX, INT32_MAX, WarpbwError, available_memory, check_count, check_device,
                           check_flag, check_instance, check_seed, is_int, numeric_array, warn_if_short_of_memory)
from warpbw.gbuffer import CameraData, GBuffer, GBufferData, check_camera_of
from warpbw.io.exr import REC709_LUMINANCE
from warpbw.pyramid import build_pyramid, image_level
from warpbw.launch import launch_tiled
from warpbw.shading import covered_pixels, pixel_frame, to_local, to_world

N_B_DEFAULT = 16              # directions per pixel; 002 Sec. 2.6 and Fig. 13 ("n_b = 16 is sufficient")
N_B_MAX = 1 << 16             # 64x the largest n_b of 002 Fig. 13's sweep (1024): a sanity bound on --nb
NYQUIST_FACTOR = 2.0          # sampling rate = 2 x bandwidth (002 Sec. 2.2, Nyquist)
N_P_MIN_DEFAULT = 1           # a shaded pixel gets at least one sample
N_P_MAX_PER_BUDGET = 256      # default n_max = 256 x budget: caps the samples one pixel may take (docstring)
BUDGET_MAX = INT32_MAX / N_P_MAX_PER_BUDGET  # largest budget whose default n_max fits the kernels' int32 N_p
ALLOCATIONS = ("variance", "sqrt", "relative", "uniform", "measured")
ALLOCATION_DEFAULT = "measured"  # N_p ~ the pass's standard deviation of the frame's estimator: +1-6 dB (docstring)
LUMINANCE = REC709_LUMINANCE   # Rec. 709's Y weights (0.2126, 0.7152, 0.0722), RGB -> scalar chi
FOUR_PI_SQ = 4.0 * math.pi * math.pi   # 002 Sec. 2.4: V(L_p) <= 4 pi^2 sigma^2 / N_p

# BRDF bandwidth table geometry: precompute.brdf_bandwidth's N_THETA_I = 16 incident elevations x N_CELLS^2 = 16 x 16
# outgoing cells (imported above)
PASS_STRIDE_DEFAULT = 2      # directions traced once per 2 x 2 block of alike pixels (module docstring)
POOL_RADIUS_DEFAULT = 2      # pixels pool the alike traced neighbours within 2 pixels (3 x 3 blocks)
# far beyond any useful pooling (a 513 x 513 window; 1e6 asked for a 7 TiB tile of shifts), and its tile's side
POOL_RADIUS_MAX = 256
INTERLEAVE_SIDE_MAX = 2 * POOL_RADIUS_MAX + 1
LIGHT_TABLE_WIDTH = 256      # fewest columns nu_env_table reduces the environment to by halves (module docstring)
ENV_BW_FORMAT = "warpbw.env-bandwidth"
# Peak memory of building a probe's bandwidth map, numpy's allocations under tracemalloc (session 62, after its
# windowed details): 213 / 168 / 151 bytes per texel at 2048x1024 / 4096x2048 / 8192x4096, which 146 bytes per
# texel plus 187 MB fits at the two larger sizes and overestimates at the smallest; rounded up.
ENV_BW_BYTES_PER_TEXEL = 150
ENV_BW_BYTES_FIXED = 200_000_000
# 5: a periodic axis whose whole periods do not fit the margin is transformed circularly on one period (session 74: the
# maps of such probes change, by more than 1% on 0.8-4.3% of their texels and by up to 35% (forest.exr resampled to 960
# x 480, 1000 x 500, 2000 x 1000, the sky at 1000 x 500); 1024 x 512 probes and the 512 x 256 sky read bit for bit the
# same); 4: periodic axes padded to whole periods, no seam (session 73; every probe's map changes, up to 22% on 0.2-3%
# of its texels); 3: rows padded past both poles come back unturned (session 73: changes maps under about 352 rows,
# such as the 512 x 256 procedural sky; 1024 x 512 probes read the same); 2: wavelet bands centred on the cascade's
# delays (session 58); 1: on one level's
ENV_BW_VERSION = 5
# The signal Eq. 7's wavelet analysis of the probe reads (``env_signal``): log(1 + L / mean L) (the default), where a
# sun no longer drowns the rest of the probe's detail, or its luminance, as 002 does (module docstring: the trade)
ENV_SIGNALS = ("log", "radiance")
ENV_SIGNAL_DEFAULT = "log"   # session 58 (module docstring); 002 reads the luminance, "radiance"
# What a probe's bandwidth map built before session 71 (or, for the signal, session 58) was built with where it
# records nothing: the radiance signal, and precompute.wavelets' defaults, unchanged since the first maps
ENV_BW_UNRECORDED = {"signal": "radiance", "wavelet": "db4", "epsilon": 0.01, "energy_fraction": 0.95}

_LUM = wp.constant(wp.vec3(*LUMINANCE))
_TWO_OVER_PI = wp.constant(2.0 / math.pi)
_TWO_PI = wp.constant(2.0 * math.pi)
_FOUR_PI_SQ = wp.constant(FOUR_PI_SQ)
# 95%-energy bandwidth of the clamped cosine max(cos theta, 0) over the incident angle, cycles/radian
# (its spectrum falls as 1/f^2 past ~1/(2 pi)); the band-limit of a Lambertian lobe's integrand
NU_COS = wp.constant(0.3)
BLOCK_DEPTH_TOL = wp.constant(0.05)   # relative depth step that separates two surfaces (module docstring)
BLOCK_NORMAL_COS = wp.constant(0.95)  # normals more than ~18 degrees apart do not share estimates
MIS_HALF = wp.constant(0.5)   # each of the two samplers is picked with probability 1/2 (one-sample MIS)
# sigma2_rel = sigma2 / (mu^2 + (REL_FLOOR m)^2), m the frame's median mu over its lit pixels: dark pixels do not
# divide by ~0, and the floor scales with the light, so "relative" does not see the exposure (an absolute 1e-4 made a
# 1000x dimmer sky's allocation "variance"; 0.04 of a Lambert sphere's median mu under the sky, 0.24, is that old 0.01)
REL_FLOOR = 0.04


@wp.struct
class BandwidthTables:
    nu_env: wp.array2d(dtype=wp.float32)   # (h, w) lat-long nu_a (cycles/radian) of the environment, max-filtered
    nu_rho: wp.array(dtype=wp.float32)     # n_materials * 16 * 16 * 16 BRDF bandwidth, cycles/radian


# ---------------------------------------------------------------------------------------------
# Warp functions and the kernel
# ---------------------------------------------------------------------------------------------
@wp.func
def brdf_nu_rho(nu_rho: wp.array(dtype=wp.float32), m: int, wi: wp.vec3, wo: wp.vec3):
    """nu_rho(w_i, w_o) of material m: nearest cell of its table (precompute.brdf_bandwidth layout)."""
    sxy = wp.sqrt(wi[0] * wi[0] + wi[1] * wi[1])
    theta_i = wp.atan2(sxy, wi[2])
    ti = wp.clamp(int(theta_i * _TWO_OVER_PI * float(N_THETA_I)), 0, N_THETA_I - 1)
    cp = 1.0
    sp = 0.0
    if sxy > 1.0e-8:
        cp = wi[0] / sxy
        sp = wi[1] / sxy
    # isotropy: turn w_o by -phi_i so that w_i lies in the table's x-z plane
    ox = cp * wo[0] + sp * wo[1]
    oy = -sp * wo[0] + cp * wo[1]
    oxy = wp.sqrt(ox * ox + oy * oy)
    r = wp.sqrt(wp.max(1.0 - wp.clamp(wo[2], 0.0, 1.0), 0.0))  # Lambert equal-area: sqrt(2) sin(theta/2)
    x = float(0.0)
    y = float(0.0)
    if oxy > 1.0e-8:
        x = r * ox / oxy
        y = r * oy / oxy
    col = wp.clamp(int((x + 1.0) * 0.5 * float(N_CELLS)), 0, N_CELLS - 1)
    row = wp.clamp(int((y + 1.0) * 0.5 * float(N_CELLS)), 0, N_CELLS - 1)
    return nu_rho[((m * N_THETA_I + ti) * N_CELLS + row) * N_CELLS + col]


@wp.func
def nu_env_at_uv(nu_env: wp.array2d(dtype=wp.float32), uv: wp.vec2):
    """nu_a of the environment at lat-long coordinates uv = env_uv(env, w): nearest texel of the reduced
    map (row centres at (j + 1/2) / h, precompute.wavelets' rows; the radiance's row j sits at v = j / (H - 1),
    warpbw.envmap's: every probe row's own direction still reads the table row that holds it, and every direction
    one holding a row of its bilinear pair: the half-texel offset stays inside a table row (session 69)."""
    h = nu_env.shape[0]
    wd = nu_env.shape[1]
    col = wp.clamp(int(uv[0] * float(wd)), 0, wd - 1)
    row = wp.clamp(int(uv[1] * float(h)), 0, h - 1)
    return nu_env[row, col]


@wp.func
def frac3(u: wp.vec3):
    """u mod 1, componentwise."""
    return wp.vec3(u[0] - wp.floor(u[0]), u[1] - wp.floor(u[1]), u[2] - wp.floor(u[2]))


@wp.func
def block_shift(shifts: wp.array(dtype=wp.vec3), side: int, i: int, width: int, stride: int, seed: int):
    """The direction-set offset of pixel i's block: shift j of the side x side tile of blocks it lies in
    (stratified within the tile, :func:`interleave_shifts`), plus one random offset per tile, so that
    different tiles look along different directions (one offset for the whole image would let a small
    bright light be missed, or hit, by every pixel at once)."""
    bx = (i % width) / stride
    by = (i / width) / stride
    tiles_x = (width + stride * side - 1) / (stride * side)
    state = wp.rand_init(seed, (by / side) * tiles_x + bx / side)
    offset = wp.vec3(wp.randf(state), wp.randf(state), wp.randf(state))
    return shifts[(by % side) * side + bx % side] + offset


@wp.func
def alike(gb: GBufferData, i: int, j: int):
    """Pixels i and j see the same surface closely enough to share bandwidth estimates: same material,
    depths within BLOCK_DEPTH_TOL, normals within acos(BLOCK_NORMAL_COS)."""
    ok = gb.material[j] == gb.material[i]
    if ok:
        di = gb.depth[i]
        ok = wp.abs(gb.depth[j] - di) <= BLOCK_DEPTH_TOL * di and wp.dot(gb.normal[i], gb.normal[j]) >= BLOCK_NORMAL_COS
    return ok


@wp.func
def block_pixel(gb: GBufferData, bx: int, by: int, k: int, stride: int):
    """Index of the k-th pixel (row-major) of block (bx, by), or -1 outside the image."""
    x = bx * stride + k % stride
    y = by * stride + k / stride
    i = int(-1)
    if x < gb.width and y < gb.height:
        i = y * gb.width + x
    return i


@wp.kernel(module="unique", enable_backward=False)
def block_plan_kernel(gb: GBufferData, stride: int, rep: wp.array(dtype=wp.int32)):
    """rep[i] = the pixel whose directions pixel i shares: the block's first pixel when every pixel of the
    stride x stride block is covered and alike, else i itself (silhouettes, depth and material edges)."""
    bx, by = wp.tid()
    first = int(-1)
    uniform = bool(True)
    for k in range(stride * stride):
        i = block_pixel(gb, bx, by, k, stride)
        if i >= 0:
            if gb.material[i] < 0:
                uniform = False
            elif first < 0:
                first = i
            elif not alike(gb, first, i):
                uniform = False
    for k in range(stride * stride):
        i = block_pixel(gb, bx, by, k, stride)
        if i >= 0:
            r = i
            if uniform:
                r = first
            if gb.material[i] < 0:
                r = -1
            rep[i] = r


@wp.kernel(module="unique", enable_backward=False)
def relative_bound_kernel(sigma2: wp.array(dtype=wp.float32), mu: wp.array(dtype=wp.float32), floor2: float,
                          sigma2_rel: wp.array(dtype=wp.float32)):
    """sigma2 / (mu^2 + floor^2): the bound relative to the pixel's own radiance ("relative" allocation).  A pixel
    with mu = 0 took no light from any direction, so its sigma2 is 0 too: 0 there when the whole frame is black."""
    i = wp.tid()
    den = mu[i] * mu[i] + floor2
    if den > 0.0:
        sigma2_rel[i] = sigma2[i] / den
    else:
        sigma2_rel[i] = 0.0


@wp.kernel(module="unique", enable_backward=False)
def pool_kernel(gb: GBufferData, rep: wp.array(dtype=wp.int32), radius: int, n_b: int, pixel_angle: float,
                lam_in: wp.array(dtype=wp.float32), nu_in: wp.array(dtype=wp.vec2), var_in: wp.array(dtype=wp.float32),
                w2_in: wp.array(dtype=wp.float32), w2b_in: wp.array(dtype=wp.float32),
                lamb_in: wp.array(dtype=wp.float32), pixels: wp.array(dtype=wp.int32), offset: int,
                nu_out: wp.array(dtype=wp.vec2), b_p: wp.array(dtype=wp.float32),
                sigma2: wp.array(dtype=wp.float32), mu_out: wp.array(dtype=wp.float32),
                var_mis: wp.array(dtype=wp.float32), var_bis: wp.array(dtype=wp.float32),
                var_step: wp.array(dtype=wp.float32)):
    """Pool the direction sums of the evaluated pixels within ``radius`` pixels that are alike (an
    interleaved set: neighbours used shifted direction sets), then Eq. 5, 6 and 9 per pixel."""
    i = pixels[wp.tid() + offset]
    W = gb.width
    H = gb.height
    x = i % W
    y = i / W
    r = rep[i]
    lam = lam_in[r]
    nu_sum = nu_in[r]
    var = var_in[r]
    var_max = var_in[r]
    w2 = w2_in[r]
    w2b = w2b_in[r]
    lamb = lamb_in[r]
    count = float(1.0)
    for yy in range(wp.max(y - radius, 0), wp.min(y + radius + 1, H)):
        for xx in range(wp.max(x - radius, 0), wp.min(x + radius + 1, W)):
            j = yy * W + xx
            if j != r and rep[j] == j and alike(gb, i, j):
                lam += lam_in[j]
                nu_sum += nu_in[j]
                var += var_in[j]
                var_max = wp.max(var_max, var_in[j])
                w2 += w2_in[j]
                w2b += w2b_in[j]
                lamb += lamb_in[j]
                count += 1.0
    nu = wp.vec2(0.0)
    if lam > 0.0:
        nu = nu_sum / lam                                         # Eq. 5
    nu_out[i] = nu
    b_p[i] = nu[1] * pixel_angle                                  # Eq. 6
    n_dirs = count * float(wp.max(n_b, 1))
    # Eq. 9: 4 pi^2 E_uniform(nu chi^2), the largest of the neighbours' estimates (Sec. 3.1's max filter)
    s2 = _FOUR_PI_SQ * var_max / (float(wp.max(n_b, 1)) * _TWO_PI)
    sigma2[i] = s2
    mu = lam / n_dirs                                             # the pass's estimate of L_p (Eq. 1)
    mu_out[i] = mu
    var_mis[i] = wp.max(w2 / n_dirs - mu * mu, 0.0)               # the directions' own one-sample MIS variance
    var_bis[i] = wp.max(w2b / n_dirs - mu * mu, 0.0)              # BRDF sampling's, from the same directions
    # the renderer's MIS step, one BRDF and one environment direction (balance heuristic): module docstring
    a_b = lamb / n_dirs
    a_e = mu - a_b
    var_step[i] = wp.max(0.5 * w2 / n_dirs - a_b * a_b - a_e * a_e, 0.0)


def make_bandwidth_kernel(kinds, preconvolved: bool = False):
    """The bandwidth-buffer kernel for the given material kinds (Eq. 9, or Eq. 10 when preconvolved)."""
    return _bandwidth_kernel(frozenset(int(k) for k in kinds), bool(preconvolved))


@functools.cache  # one kernel per combination: Warp compiles each once
def _bandwidth_kernel(kinds: frozenset, preconvolved: bool):
    f = make_brdf_funcs(kinds)

    @wp.kernel(module="unique", enable_backward=False)
    def bandwidth_buffer_kernel(gb: GBufferData, cam: CameraData, mats: MaterialTable, env: EnvMapData,
                                tables: BandwidthTables, dirs: wp.array(dtype=wp.vec3),
                                shifts: wp.array(dtype=wp.vec3), side: int, stride: int, seed: int,
                                pixels: wp.array(dtype=wp.int32), offset: int,
                                lam_out: wp.array(dtype=wp.float32), nu_out: wp.array(dtype=wp.vec2),
                                var_out: wp.array(dtype=wp.float32), w2_out: wp.array(dtype=wp.float32),
                                w2b_out: wp.array(dtype=wp.float32), lamb_out: wp.array(dtype=wp.float32)):
        i = pixels[wp.tid() + offset]
        m = gb.material[i]
        fr = pixel_frame(gb, i)
        wo = fr.wo
        dp = wp.length(gb.position[i] - cam.origin)  # d': surface to the eye
        c = gb.curvature[i]
        shift = block_shift(shifts, side, i, gb.width, stride, seed)
        lam_sum = float(0.0)
        nu_sum = wp.vec2(0.0)
        var_sum = float(0.0)
        w2_sum = float(0.0)
        w2b_sum = float(0.0)
        lamb_sum = float(0.0)
        if wo[2] > 0.0:
            for k in range(dirs.shape[0]):
                u = frac3(dirs[k] + shift)
                # one-sample MIS of the BRDF and light samplers, each picked with probability 1/2 (u[0])
                wi = wp.vec3(0.0)
                if u[0] < 0.5:
                    wi = f.sample(mats, m, wo, wp.vec3(2.0 * u[0], u[1], u[2]))
                else:
                    wi = to_local(fr, env_sample(env, wp.vec2(u[1], u[2])))
                if wi[2] > 0.0:
                    wi_world = to_world(fr, wi)
                    uv = env_uv(env, wi_world)                   # once: the pdf, L_i and nu_a need it
                    p_b = f.pdf(mats, m, wi, wo)
                    pdf = MIS_HALF * (p_b + env_pdf_uv(env, uv))
                    # lambda_i (Eq. 5), Eq. 1's integrand: the luminance of L rho cos (module docstring)
                    chi = wp.dot(_LUM, wp.cw_mul(env_radiance_uv(env, uv), f.eval(mats, m, wi, wo))) * wi[2]
                    nu_l = nu_env_at_uv(tables.nu_env, uv)
                    nu_r = brdf_nu_rho(tables.nu_rho, m, wi, wo)
                    # the shading integral over w_i keeps only the light's angular frequencies within the
                    # band of rho cos (Eq. 8's convolution, read at angular frequency 0): module docstring
                    nu_in = wp.min(nu_l, nu_r + NU_COS)
                    nu_i = bw_one_bounce(wp.vec2(0.0, nu_in), 0.0, dp, wi[2], wo[2], c, 0.0, nu_r)  # Eq. 4
                    w = chi / pdf                                 # importance weight of direction i
                    if chi > 0.0 and pdf > 0.0 and wp.isfinite(w):
                        lam_sum += w
                        w2_sum += w * w
                        lamb_sum += w * MIS_HALF * p_b / pdf      # the BRDF direction's share, p_b / (p_b + p_env)
                        if p_b > 0.0:
                            t = w * chi / p_b                     # chi^2 / (p_b q): E_q of it is E_p_b[(chi / p_b)^2]
                            if wp.isfinite(t):
                                w2b_sum += t
                        nu_sum += w * nu_i
                        if wp.static(preconvolved):
                            var_sum += (2.0 * nu_r + NU_COS) * chi * w  # Eq. 10, + the cosine's band
                        else:
                            var_sum += (nu_l + nu_r + NU_COS) * chi * w  # Eq. 9, + the cosine's band
        lam_out[i] = lam_sum
        nu_out[i] = nu_sum
        var_out[i] = var_sum
        w2_out[i] = w2_sum
        w2b_out[i] = w2b_sum
        lamb_out[i] = lamb_sum

    return bandwidth_buffer_kernel


# ---------------------------------------------------------------------------------------------
# Host side
# ---------------------------------------------------------------------------------------------
def _reduce_latlong(a: np.ndarray, fy: int, fx: int, op) -> np.ndarray:
    h, w = a.shape
    return op(a.reshape(h // fy, fy, w // fx, fx), axis=(1, 3))


def nu_env_table(nu_env: np.ndarray, width: int = None) -> np.ndarray:
    """The bandwidth pass's view of the environment's angular bandwidth, ``(h, w)`` float32 cycles/radian.

    nu_a max-filtered (conservative) over blocks of 2^k x 2^k texels, the largest 2^k that divides both sides and
    leaves at least ``LIGHT_TABLE_WIDTH`` (``width``) columns: 256 of a probe 2^n >= 256 wide, but 500 of a
    1000 x 500 probe, and a map with an odd side is not reduced (the docstring said "at most" until session 73).
    One nearest look-up per direction instead of a bilinear one; each of the pass's n_b directions stands for
    2 pi / n_b sr, far more than a reduced texel (2 pi^2 / (h w) sr at the equator).  The radiance L_i
    is read from the map itself (module docstring)."""
    nu = np.asarray(nu_env, np.float64)
    if nu.ndim != 2 or nu.size == 0:
        raise WarpbwError(f"environment bandwidth table: expected a non-empty (h, w) map, got shape {nu.shape}")
    if not (np.all(np.isfinite(nu)) and nu.min() >= 0.0):   # passed through into the pass's weights
        raise WarpbwError(f"environment bandwidth table: expected finite bandwidths >= 0, got values from "
                          f"{nu.min():.3g} to {nu.max():.3g}")
    h, w = nu.shape
    width = LIGHT_TABLE_WIDTH if width is None else check_count(width, "width", 1)
    f = 1
    while w % (2 * f) == 0 and h % (2 * f) == 0 and w // (2 * f) >= width:
        f *= 2
    return _reduce_latlong(nu, f, f, np.max).astype(np.float32)


def make_bandwidth_tables(nu_env, nu_rho, device: str = "cpu") -> tuple[BandwidthTables, list]:
    """Device copies of the environment's bandwidth table (h, w) (:func:`nu_env_table`) and the stacked BRDF
    tables (M, 16, 16, 16).  Returns the struct and the arrays it references (keep them alive with it)."""
    check_device(device)
    lt = np.ascontiguousarray(numeric_array(nu_env, "environment bandwidth table", "(h, w) bandwidths"), np.float32)
    rho = np.ascontiguousarray(numeric_array(nu_rho, "BRDF bandwidth tables", "bandwidths"), np.float32)
    if lt.ndim != 2 or lt.size == 0:
        raise WarpbwError(f"environment bandwidth table: expected a non-empty (h, w) array, got shape {lt.shape}")
    if rho.ndim != 4 or rho.shape[1:] != (N_THETA_I, N_CELLS, N_CELLS) or rho.shape[0] == 0:
        # no table at all was taken, and the pass then read material 0's past the end (a segfault)
        raise WarpbwError(f"BRDF bandwidth tables: expected shape (materials, {N_THETA_I}, {N_CELLS}, {N_CELLS}) with "
                          f"one table per material (at least one), got {rho.shape}")
    for name, a in (("environment bandwidth table", lt), ("BRDF bandwidth tables", rho)):
        if not np.all(np.isfinite(a)) or np.any(a < 0):
            raise WarpbwError(f"{name}: values must be finite and >= 0")
    s = BandwidthTables()
    s.nu_env = wp.array(lt, dtype=wp.float32, device=device)
    s.nu_rho = wp.array(rho.reshape(-1), dtype=wp.float32, device=device)
    return s, [s.nu_env, s.nu_rho]


def check_env_signal(signal: str) -> str:
    """``signal`` if it is one of ``ENV_SIGNALS``, else a one-line error naming them."""
    if signal not in ENV_SIGNALS:
        raise WarpbwError(f"env_signal: expected one of {', '.join(ENV_SIGNALS)}, got {signal!r}")
    return signal


def env_signal(lum: np.ndarray, signal: str = ENV_SIGNAL_DEFAULT) -> np.ndarray:
    """The map the wavelet analysis of the probe reads: its luminance ``lum`` itself ("radiance", 002's), or
    log(1 + L / mean L) ("log", float64): linear in L below the probe's mean, logarithmic above it, so that a sun
    compressed to a few times the sky's level no longer fills the coarse bands of every texel within reach of its
    wavelets."""
    if check_env_signal(signal) == "log":
        lum = numeric_array(lum, "env_signal: lum", "luminance values")
        # the mean in float64: a float32 sum of a probe at 1e36 overflowed to inf (numpy warned, the log read 0)
        mean = float(np.mean(lum)) if lum.size else math.nan
        if not (math.isfinite(mean) and mean > 0.0 and lum.min() >= 0.0):   # a black map's 0 / 0: NaN at every texel
            raise WarpbwError(f"env_signal: the log signal divides the luminance by its mean: expected finite "
                              f"luminance >= 0 with a mean > 0, got mean {mean:g}" + (f", minimum {lum.min():g}"
                                                                                     if lum.size else ""))
        return np.log1p(lum / mean)
    return lum


def env_bandwidth_memory(width: int, height: int) -> int:
    """Bytes building the bandwidth map of a ``width`` x ``height`` probe takes at the peak
    (``ENV_BW_BYTES_PER_TEXEL`` and ``ENV_BW_BYTES_FIXED``)."""
    return ENV_BW_BYTES_PER_TEXEL * int(width) * int(height) + ENV_BW_BYTES_FIXED


def env_bandwidth_settings(signal: str = ENV_SIGNAL_DEFAULT) -> dict:
    """The settings ``env_bandwidth_map`` builds a map of ``signal`` with, as its cache entry's ``params`` records them
    (``precompute.wavelets``' constants, read now; beside them it records the units and the floor's rule, which name
    what the map is): an entry that records others is rebuilt."""
    from precompute import wavelets

    return {"signal": check_env_signal(signal), "wavelet": wavelets.DEFAULT_WAVELET, "epsilon": wavelets.EPSILON,
            "energy_fraction": wavelets.ENERGY_FRACTION}


def env_bandwidth_map(pixels: np.ndarray, name: str = "environment", cache=None,
                      signal: str = ENV_SIGNAL_DEFAULT, progress: bool = False,
                      source: str | None = None) -> tuple[np.ndarray, str]:
    """nu_a(w) of a lat-long probe in cycles/radian (002 Sec. 2.3, "Distant illumination").

    Wavelet analysis of the map's :func:`env_signal` (:func:`precompute.wavelets.envmap_angular_bandwidth`, about
    5 s at 1024x512 on one core), with the flatness floor at ``EPSILON`` times the signal's mean (an HDR sun
    would otherwise make every other texel flat), cached by the pixels' content hash and the signal in ``cache``
    (a path or a str; default ``$WARPBW_CACHE``).  The map does not see the probe's exposure (either signal); given
    ``source``, the hash of the probe before its scale (``EnvMap.source_digest``), the cache is keyed by it instead, so
    that the probe at another ``[environment] scale`` reads the entry (``pixels`` must then be that probe times a
    scale > 0).  A constant map has bandwidth 0 everywhere.  An empty map, one with
    NaN or infinite pixels, or one beyond float32's range is refused, naming ``name``.  Returns the map and where
    it came from ("constant", "cache" or "built").  ``progress`` shows a bar over the wavelet bands while it builds
    (a minute at 8192x4096); a build that would take more memory than is available (``ENV_BW_BYTES_PER_TEXEL``,
    5 GB at 8192x4096) warns first.  A cache entry whose recorded settings are not ``env_bandwidth_settings(signal)``
    (``precompute.assetfile.settings_mismatch``, with ``ENV_BW_UNRECORDED`` for what older entries lack) is stale:
    rebuilt and replaced, as a damaged one is."""
    from precompute.assetfile import read_asset, settings_mismatch, write_asset
    from precompute.brdf_sampling import cache_dir
    from precompute.progress import progress_callback
    from precompute.wavelets import envmap_angular_bandwidth, envmap_bandwidth_max
    from warpbw.io.staged import remove_stale_temps

    settings = env_bandwidth_settings(signal)
    if source is not None and not (isinstance(source, str) and re.fullmatch(r"[\w-]+:[0-9a-f]+", source)):
        # it names the cache file: "sha256-source:" and hex digits (EnvMap.source_digest)
        raise WarpbwError(f"source: expected the probe's source digest (\"NAME:HEX\", EnvMap.source_digest), "
                          f"got {source!r}")
    raw = np.asarray(pixels)
    if raw.ndim != 3 or raw.shape[2] != 3 or raw.size == 0 or raw.dtype.kind not in "biuf":
        raise WarpbwError(f"{name}: expected non-empty (H, W, 3) pixels for the bandwidth map, got shape {raw.shape} "
                          f"{raw.dtype}")
    n_bad = int(np.count_nonzero(~np.isfinite(raw)))
    if n_bad:   # the wavelet analysis said "image has NaN or infinite values", without naming the map
        raise WarpbwError(f"{name}: {n_bad} of {raw.size} pixel values are NaN or infinite; expected finite radiance "
                          "for the bandwidth map")
    big = float(np.abs(raw).max())
    if big > FLOAT32_MAX:   # the float32 cast below made them inf, reported as "NaN or infinite"
        raise WarpbwError(f"{name}: pixel values up to {big:.3g} exceed float32's range ({FLOAT32_MAX:.4g}); "
                          "expected radiance the renderer can hold (scale the map down)")
    px = np.ascontiguousarray(raw, np.float32)
    h, w = px.shape[:2]
    lum = px @ np.asarray(LUMINANCE, np.float32)
    if float(np.ptp(lum)) == 0.0:
        return np.zeros((h, w), np.float32), "constant"
    digest = source or "blake2b:" + hashlib.blake2b(px.tobytes() + str(px.shape).encode(), digest_size=16).hexdigest()
    kind = "" if signal == "radiance" else f"{signal}-"   # the radiance maps keep their cache names
    if cache is not None and not isinstance(cache, (str, os.PathLike)):   # 5: pathlib's TypeError
        raise WarpbwError(f"cache: expected a folder (a path or a str), got {type(cache).__name__}")
    path = ((cache_dir() if cache is None else Path(cache))   # a str failed on str / str
            / f"env-bandwidth-{kind}{digest.split(':')[1]}-v{ENV_BW_VERSION}.npz")
    remove_stale_temps(path)   # a killed writer's, where another run wrote the entry whole: none writes it again
    if path.is_file():
        try:
            a = read_asset(path, ENV_BW_FORMAT, ENV_BW_VERSION, "delete the cache file")
            with np.errstate(over="ignore"):   # float64 beyond float32 becomes inf, a stale entry (numpy warned)
                nu = np.asarray(a.arrays["nu_a"], np.float32)
            if (a.header.get("source_hash") == digest and nu.shape == (h, w) and a.arrays["nu_a"].dtype.kind == "f"
                    and settings_mismatch(a.header.get("params"), settings, ENV_BW_UNRECORDED) is None
                    and np.isfinite(nu).all() and (nu >= 0).all()   # a bandwidth is a finite rate, at most what
                    # the analysis gives: a damaged entry at 3e38 was read and blamed on the light's radiance
                    and (nu <= envmap_bandwidth_max(h) * (1.0 + 1e-6)).all()):
                return nu, "cache"
        except (WarpbwError, KeyError, AttributeError, TypeError, ValueError):
            pass  # a stale or damaged cache entry (strings for numbers: a ValueError) is rebuilt below
    # a minute and 5 GB at 8192x4096: warn first where that is more than the system has (it stops a process that
    # runs out without a word)
    warn_if_short_of_memory(env_bandwidth_memory(w, h), available_memory(),
                            f"building the bandwidth map of {name} ({w}x{h})",
                            "a smaller probe; the reference method does not build it")
    t = env_signal(lum, signal).astype(np.float64)     # a float32 mean overflows beyond about 1e33 per texel
    with progress_callback(1, f"bandwidth {name}", "band", progress) as step:
        nu = envmap_angular_bandwidth(t, settings["epsilon"], settings["wavelet"],
                                      floor=settings["epsilon"] * float(t.mean()), progress=step,
                                      energy_fraction=settings["energy_fraction"]).astype(np.float32)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_asset(path, ENV_BW_FORMAT, ENV_BW_VERSION, name, digest, {"nu_a": nu},
                    params={"units": "cycles/radian", "floor": "epsilon * mean signal", **settings}, force=True)
    except (OSError, WarpbwError):
        pass  # a read-only or full cache (write_asset says which, as a WarpbwError) only costs the rebuild next time
    return nu, "built"


def _radical_inverse(k: np.ndarray, base: int) -> np.ndarray:
    """Van der Corput radical inverse of the integers k in ``base``."""
    k = k.astype(np.int64)
    out = np.zeros(k.shape, np.float64)
    scale = 1.0 / base
    while np.any(k):
        out += (k % base) * scale
        k //= base
        scale /= base
    return out


def _check_n_b(n_b) -> int:
    if not is_int(n_b) or not 1 <= n_b <= N_B_MAX:
        raise WarpbwError(f"n_b: expected an integer number of directions from 1 to {N_B_MAX} (002 Fig. 13 sweeps "
                          f"16 to 1024), got {n_b!r}")
    return int(n_b)


def direction_set(n_b: int, seed: int = 0) -> np.ndarray:
    """``(n_b, 3)`` float32 Hammersley points ``((k + 1/2) / n_b, phi_2(k), phi_3(k))`` shifted by a seeded
    offset mod 1 (Cranley-Patterson).  u[0] picks the sampler (BRDF below 1/2, light above: half of the
    points each, exactly when n_b is even) and (u[1], u[2]) the direction."""
    k = np.arange(_check_n_b(n_b))
    shift = np.random.default_rng(check_seed(seed)).random(3)   # None drew a different set at every call
    u = np.stack([(k + 0.5) / n_b + shift[0], _radical_inverse(k, 2) + shift[1],
                  _radical_inverse(k, 3) + shift[2]], axis=1) % 1.0
    return u.astype(np.float32)


def pixel_angle(cam: CameraData) -> float:
    """max(f_x / W, f_y / H) of Eq. 6: radians per pixel (full fields of view f_x, f_y)."""
    check_instance(cam, CameraData, "pixel_angle: cam", "a CameraData (make_camera's)")
    fx = 2.0 * math.atan(cam.tan_half_x)
    fy = 2.0 * math.atan(cam.tan_half_y)
    return max(fx / cam.width, fy / cam.height)


def load_kernels(device: str = "cpu", relative: bool = True) -> None:
    """Load (compile) the pass's block-plan and pooling kernels, and with ``relative`` the relative bound's, so that
    ``bandwidth_pass`` times only the pass (``make_bandwidth_kernel``'s kernel is loaded by the pipeline beside the
    others it builds)."""
    check_device(device)
    relative = check_flag(relative, "load_kernels: relative")
    for k in (block_plan_kernel, pool_kernel) + ((relative_bound_kernel,) if relative else ()):
        wp.load_module(k.module, device=device)


def _median_lit(mu: wp.array, coverage: np.ndarray) -> float:
    """The median of ``mu`` over the covered pixels it lights (mu > 0); 0 where none is lit."""
    lit = mu.numpy()[coverage.reshape(-1)]
    lit = lit[lit > 0.0]
    return float(np.median(lit)) if lit.size else 0.0


@dataclass
class BandwidthBuffer:
    """The bandwidth buffer of one frame; flat row-major arrays of H*W (0 where no geometry)."""

    nu: wp.array               # vec2 [nu_s, nu_a] at the eye (Eq. 5)
    b_p: wp.array              # float32 image bandwidth, cycles/pixel (Eq. 6)
    sigma2: wp.array           # float32 variance bound numerator: V(L_p) <= sigma2 / N_p (Eq. 9 / 10)
    sigma2_rel: wp.array | None   # float32 sigma2 / (mu^2 + (REL_FLOOR m)^2), m the frame's median lit mu
                                  # (None: a pass without ``relative``, for an allocation that does not read it)
    level: wp.array            # int32 (H, W) shading level (Eq. 11 on NYQUIST_FACTOR * b_p)
    coverage: np.ndarray       # (H, W) bool
    width: int
    height: int
    n_b: int
    time_s: float = 0.0
    traced_pixels: int = 0     # pixels whose n_b directions were traced (the rest share a block's)
    variance_mis: wp.array | None = None   # float32 variance of the directions' one-sample MIS estimates of L_p
    variance_bis: wp.array | None = None   # float32 variance of BRDF sampling's estimate, from the same directions
    mu: wp.array | None = None             # float32 the pass's own estimate of L_p's luminance (Eq. 1), pooled
    variance_step: wp.array | None = None  # float32 variance of the renderer's MIS step (a BRDF and an environment
                                           # direction, balance heuristic), from the same directions

    def estimator_variance(self, mis: bool = True) -> wp.array | None:
        """The measured variance of the frame's estimator: MIS's step (a BRDF and an environment direction,
        ``variance_step``; the one-sample ``variance_mis`` where a buffer lacks it), or BRDF sampling's alone (where
        measured)."""
        mis = check_flag(mis, "estimator_variance: mis")   # "no" is truthy: MIS's variance
        if not mis and self.variance_bis is not None:
            return self.variance_bis
        return self.variance_mis if self.variance_step is None else self.variance_step

    def measured_key(self, mis: bool = True) -> wp.array | None:
        """The "measured" allocation's key: with MIS the one-sample ``variance_mis``, which allocates better than the
        step's own variance on the benchmark (module docstring, session 74), without it ``variance_bis``."""
        mis = check_flag(mis, "measured_key: mis")
        return self.variance_mis if mis or self.variance_bis is None else self.variance_bis

    def median_lit_mu(self) -> float:
        """The frame's median ``mu`` over its lit pixels (covered, mu > 0); 0 where none is lit."""
        return _median_lit(self.mu, self.coverage)


def interleave_shifts(n_b: int, side: int) -> np.ndarray:
    """``(side^2, 3)`` offsets (mod 1) of the direction set for an interleaved ``side x side`` tile of
    blocks: shift j = (j / (side^2 n_b), phi_2(j) / n_b, phi_3(j) / n_b), so that the tile's shifted
    Hammersley sets together stratify side^2 times more finely than one set."""
    _check_n_b(n_b)   # 0 gave inf shifts
    t = check_count(side, "side", 1, INTERLEAVE_SIDE_MAX) ** 2
    j = np.arange(t)
    return np.stack([j / (t * n_b), _radical_inverse(j, 2) / n_b, _radical_inverse(j, 3) / n_b],
                    axis=1).astype(np.float32)


def _check_pass_inputs(gb, cam, materials, env_data, tables) -> None:
    """The pass's structs, by type and size (not contents: it runs every frame): the kernel reads the BRDF table of
    every material the G-buffer names, so a stack of fewer tables than materials was read past its end (a
    segfault), and None or a float64 array failed inside Warp."""
    for name, value, kind, what in (
            ("gb", gb, GBuffer, "a GBuffer (render_gbuffer)"), ("cam", cam, CameraData.cls, "a CameraData"),
            ("materials", materials, MaterialBuffers, "MaterialBuffers (build_material_table)"),
            ("tables", tables, BandwidthTables.cls, "BandwidthTables (make_bandwidth_tables)")):
        if not isinstance(value, kind):
            raise WarpbwError(f"bandwidth pass: {name}: expected {what}, got {type(value).__name__}")
    check_env_data(env_data, "bandwidth pass", sampled=True)   # its directions sample the environment
    check_sampling_tables(materials, "bandwidth pass", gb.data.material)   # and the BRDFs
    check_camera_of(cam, gb, "bandwidth pass")
    n_mat = materials.table.kind.shape[0] if materials.table.kind is not None else 0
    per_material = N_THETA_I * N_CELLS * N_CELLS
    rho, env = tables.nu_rho, tables.nu_env
    if rho is None or env is None or rho.shape[0] < n_mat * per_material or rho.shape[0] % per_material:
        got = "none" if rho is None else f"{rho.shape[0]} values"
        raise WarpbwError(f"bandwidth pass: tables: expected a BRDF bandwidth table ({per_material} values) for each "
                          f"of the {n_mat} materials, got {got} (make_bandwidth_tables with one table per material)")
    if env.shape[0] == 0 or env.shape[1] == 0:
        raise WarpbwError(f"bandwidth pass: tables: expected a non-empty environment bandwidth table, got shape "
                          f"{env.shape}")


def bandwidth_pass(gb: GBuffer, cam: CameraData, materials: MaterialBuffers, env_data: EnvMapData,
                   tables: BandwidthTables, n_b: int = N_B_DEFAULT, seed: int = 0, preconvolved: bool = False,
                   nyquist: float = NYQUIST_FACTOR, stride: int = PASS_STRIDE_DEFAULT,
                   pool_radius: int = POOL_RADIUS_DEFAULT, device: str = "cpu",
                   threads: int | None = None, relative: bool = True) -> BandwidthBuffer:
    """Fill the bandwidth buffer: nu, b_p, sigma2 per covered pixel, and the level map (Eq. 11); with ``relative``
    also ``sigma2_rel``, which only the "relative" allocation reads (else None).

    ``stride``: the directions are traced once per ``stride x stride`` block of alike pixels (every pixel
    of a block at a silhouette or an edge is traced); ``pool_radius``: each pixel pools the sums of the
    alike traced pixels within that many pixels (interleaved direction sets).  ``stride=1, pool_radius=0``
    is the plain per-pixel pass of 002 Sec. 3.1.  The pass predicts the environment's part of the image:
    directional lights are not up-sampled but added exactly at every pixel (:mod:`warpbw.adaptive`), so
    they take no part in it."""
    check_device(device)
    import time

    if env_data is None:
        raise WarpbwError("bandwidth pass: the scene has no environment (directional lights need no prediction: "
                          "their exact term is evaluated at every pixel)")
    _check_pass_inputs(gb, cam, materials, env_data, tables)
    preconvolved = check_flag(preconvolved, "bandwidth pass: preconvolved")   # "yes" ran Eq. 10 as truthy
    dirs_np = direction_set(n_b, seed)
    stride = check_count(stride, "stride", 1, max(gb.width, gb.height))   # beyond the image's side it shares no more
    pool_radius = check_count(pool_radius, "pool_radius", 0, POOL_RADIUS_MAX)
    # the rate is float32 in the kernels; True was taken as 1
    if not (isinstance(nyquist, numbers.Real) and not isinstance(nyquist, (bool, np.bool_))
            and 0 < nyquist <= FLOAT32_MAX):
        raise WarpbwError(f"nyquist: expected a positive factor within the float32 range "
                          f"(<= {FLOAT32_MAX:.4g}), got {nyquist!r}")
    t0 = time.perf_counter()
    W, H = gb.width, gb.height
    # the tile of shifts: enough that the pooling window sees each once (its width in blocks)
    side = 1 if pool_radius == 0 else (2 * pool_radius) // stride + 1
    dirs = wp.array(dirs_np, dtype=wp.vec3, device=device)
    shifts = wp.array(interleave_shifts(n_b, side), dtype=wp.vec3, device=device)
    rep = wp.empty(W * H, dtype=wp.int32, device=device)
    wp.launch(block_plan_kernel, dim=((W + stride - 1) // stride, (H + stride - 1) // stride),
              inputs=[gb.data, stride, rep], device=device)
    rep_np = rep.numpy()
    traced = wp.array(np.flatnonzero(rep_np == np.arange(W * H)).astype(np.int32), dtype=wp.int32, device=device)
    lam = wp.zeros(W * H, dtype=wp.float32, device=device)
    nu_sum = wp.zeros(W * H, dtype=wp.vec2, device=device)
    var = wp.zeros(W * H, dtype=wp.float32, device=device)
    w2 = wp.zeros(W * H, dtype=wp.float32, device=device)
    w2b = wp.zeros(W * H, dtype=wp.float32, device=device)
    lamb = wp.zeros(W * H, dtype=wp.float32, device=device)
    kernel = make_bandwidth_kernel(materials.kinds, preconvolved)
    launch_tiled(kernel, traced.shape[0],
                 lambda o, c: [gb.data, cam, materials.table, env_data, tables, dirs, shifts, side, stride, int(seed),
                               traced, o, lam, nu_sum, var, w2, w2b, lamb], device, threads, item_cost=int(n_b))
    nu = wp.zeros(W * H, dtype=wp.vec2, device=device)
    b_p = wp.zeros(W * H, dtype=wp.float32, device=device)
    sigma2 = wp.zeros(W * H, dtype=wp.float32, device=device)
    mu = wp.zeros(W * H, dtype=wp.float32, device=device)
    var_mis = wp.zeros(W * H, dtype=wp.float32, device=device)
    var_bis = wp.zeros(W * H, dtype=wp.float32, device=device)
    var_step = wp.zeros(W * H, dtype=wp.float32, device=device)
    pix = covered_pixels(gb, device)
    angle = pixel_angle(cam)
    launch_tiled(pool_kernel, pix.shape[0],
                 lambda o, c: [gb.data, rep, pool_radius, int(n_b), angle, lam, nu_sum, var, w2, w2b, lamb, pix, o,
                               nu, b_p, sigma2, mu, var_mis, var_bis, var_step], device, threads)
    sigma2_rel = None
    if check_flag(relative, "bandwidth pass: relative"):
        floor = REL_FLOOR * _median_lit(mu, gb.coverage)
        sigma2_rel = wp.empty(W * H, dtype=wp.float32, device=device)   # relative_bound_kernel writes every pixel
        wp.launch(relative_bound_kernel, dim=W * H, inputs=[sigma2, mu, floor * floor, sigma2_rel], device=device)
    with np.errstate(over="ignore"):  # a rate beyond float32 is +inf: level 0 (image_level)
        rate = b_p.numpy() * np.float32(nyquist)
    level = image_level(rate, gb.coverage, W, H, device=device)
    wp.synchronize_device(device)
    return BandwidthBuffer(nu, b_p, sigma2, sigma2_rel, level, gb.coverage, W, H, int(n_b),
                           time.perf_counter() - t0, int(traced.shape[0]), var_mis, var_bis, mu, var_step)


@dataclass
class SampleAllocation:
    n_p: np.ndarray            # (H, W) int32 samples per pixel (0 where no geometry)
    variance: np.ndarray       # (H, W) float32 predicted variance of an estimate of N_p samples, v / N_p (0 where no
                               # geometry): v the variance the pass measured for the frame's estimator ("measured")
                               # or the bound sigma2 (Eq. 9 / 10; every other allocation, "relative" included)
    v_target: float            # the constant V of N_p = ceil(sigma2 / V); 0: all at n_max; inf (null in JSON):
                               # all at n_min, or no pixel planned
    planned_pixels: int        # pixels the hierarchy is expected to shade
    planned_samples: int       # samples those pixels will take
    budget_samples: int        # budget x covered pixels
    over_budget: bool          # n_min per planned pixel already exceeds the budget
    stats: dict = field(default_factory=dict)


def _n_of(s: np.ndarray, v: float, n_min: int, n_max: int, sanitised: bool = False) -> np.ndarray:
    """N_p = ceil(s / v) within [n_min, n_max] (a non-finite s, or v = 0: n_max).  ``sanitised``: ``s`` holds inf
    where it was not finite and ``v`` is finite and > 0, so no NaN can arise and two passes over ``s`` are left out
    (the bisection calls this 60 times a frame: 10 ms of the gold bunny's 364 at budget 4, session 62)."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if sanitised and 0.0 < v < math.inf:
            return np.clip(np.ceil(s / v), n_min, n_max).astype(np.int64)
        n = np.ceil(np.where(np.isfinite(s), s, np.inf) / v)
    return np.clip(np.nan_to_num(n, nan=n_max, posinf=n_max), n_min, n_max).astype(np.int64)


def planned_shading(buf: BandwidthBuffer, device: str = "cpu", key=None, plan=None) -> np.ndarray:
    """sigma2 (or ``key``) of the texels the hierarchy will shade, max-filtered over their footprints.  ``plan``:
    per level, finest first, a (h_L, w_L) bool mask of those texels (``warpbw.adaptive.HierarchyPlan.shade_masks``,
    which knows the texels the up-sampling cannot fill); without one, the level-L texels of some coverage whose
    min-filtered level is L; the HierarchyPlan itself is read as its masks."""
    check_device(device)
    check_instance(buf, BandwidthBuffer, "buf", "a BandwidthBuffer (bandwidth_pass's)")
    if callable(getattr(plan, "shade_masks", None)):   # the plan itself: a TypeError ("no len()") before
        plan = plan.shade_masks()
    W, H = buf.width, buf.height
    var = build_pyramid((buf.sigma2 if key is None else key).numpy().reshape(H, W), op="max", device=device)
    if plan is None:
        levels = build_pyramid(buf.level, op="min", device=device)
        cov = build_pyramid(buf.coverage.astype(np.int32), op="max", device=device)
        cov_np = buf.coverage
        top = int(buf.level.numpy()[cov_np].max()) if cov_np.any() else 0
        top = min(top, levels.num_levels - 1)
        plan = [(levels.levels[L].numpy() == L) & (cov.levels[L].numpy() > 0) for L in range(top + 1)]
    if (not isinstance(plan, (list, tuple)) or len(plan) > var.num_levels
            or any(np.shape(m) != tuple(var.shapes[L]) for L, m in enumerate(plan))):
        raise WarpbwError(f"plan: expected a HierarchyPlan or up to {var.num_levels} bool masks, finest first, of "
                          f"shapes {[tuple(s) for s in var.shapes]}, got {type(plan).__name__}")
    out = [var.levels[L].numpy()[np.asarray(m, bool)] for L, m in enumerate(plan)]
    return np.concatenate(out) if out else np.zeros(0, np.float32)


def allocate_samples(buf: BandwidthBuffer, budget: float, n_min: int = N_P_MIN_DEFAULT, n_max: int | None = None,
                     allocation: str = ALLOCATION_DEFAULT, device: str = "cpu", mis: bool = True,
                     plan=None) -> SampleAllocation:
    """N_p per pixel for ``budget`` samples per covered pixel, spread over the texels the hierarchy will shade
    (``plan``, as ``planned_shading`` reads it): proportional to sigma2 ("variance", 002
    Sec. 2.4: constant variance), to its square root ("sqrt"), to sigma2 / L^2 ("relative"), constant
    ("uniform"), or to the standard deviation the pass measured for the renderer's estimator ("measured":
    the allocation that minimises the summed variance for a fixed budget; ``mis`` says which estimator,
    MIS or BRDF sampling alone: True by default, where ``render_adaptive``'s frames default to BRDF sampling, so
    pass the frame's own, as ``render_adaptive`` does).  A key that is not finite and >= 0 at a covered pixel (the
    pass's float32 squares overflowed) is refused: no N_p then keeps the budget.  Module docstring."""
    check_device(device)
    check_instance(buf, BandwidthBuffer, "allocate_samples: buf", "a BandwidthBuffer (bandwidth_pass's)")
    mis = check_flag(mis, "mis")
    if allocation not in ALLOCATIONS:
        raise WarpbwError(f"allocation: expected one of {', '.join(ALLOCATIONS)}, got {allocation!r}")
    if isinstance(budget, bool) or not isinstance(budget, (int, float, np.integer, np.floating)) \
            or not (budget > 0 and math.isfinite(budget)):
        raise WarpbwError(f"budget: expected a positive number of samples per pixel, got {budget!r}")
    check_count(n_min, "n_min", 1, INT32_MAX)
    check_flag(mis, "mis")
    if n_max is None:
        if budget > BUDGET_MAX:
            raise WarpbwError(f"budget: expected at most {BUDGET_MAX:g} samples per pixel (N_p, up to "
                              f"{N_P_MAX_PER_BUDGET} x budget, is an int32 in the kernels), got {budget:g}")
        n_max = max(int(n_min), int(math.ceil(N_P_MAX_PER_BUDGET * budget)))
    if not is_int(n_max) or not n_min <= n_max <= INT32_MAX:  # N_p is an int32 in the kernels
        raise WarpbwError(f"n_max: expected an integer from n_min ({n_min}) to {INT32_MAX}, got {n_max!r}")
    W, H = buf.width, buf.height
    cov = buf.coverage
    n_cov = int(cov.sum())
    total = int(round(budget * n_cov))
    power = {"sqrt": 0.5, "uniform": 0.0, "measured": 0.5}.get(allocation, 1.0)
    key = {"relative": buf.sigma2_rel, "measured": buf.measured_key(mis)}.get(allocation, buf.sigma2)
    if key is None:
        lacks = ("relative bound (bandwidth_pass(..., relative=True) derives it)" if allocation == "relative"
                 else "measured variance")
        raise WarpbwError(f"allocation {allocation!r}: the bandwidth buffer has no {lacks}")
    sig = key.numpy().reshape(H, W).astype(np.float64)
    bad = cov & ~(np.isfinite(sig) & (sig >= 0.0))
    if bad.any():   # an inf (overflowed) value set hi = inf in the bisection: N_p = n_max there, n_min elsewhere,
        # and the frame took n_max x the budget with over_budget False; the variance AOV read inf
        raise WarpbwError(f"allocation {allocation!r}: the bandwidth buffer's variance is not a finite number >= 0 at "
                          f"{int(bad.sum())} of {n_cov} covered pixels (e.g. {sig[bad][0]:g}: the pass's squared "
                          "radiance overflowed float32); expected lower radiance")
    s = planned_shading(buf, device, key, plan).astype(np.float64) ** power
    n_plan = len(s)
    over = n_plan * n_min > total
    if n_plan == 0:
        v = math.inf
    elif over:
        v = math.inf  # every shaded pixel at n_min
    elif n_plan * n_max <= total or not np.any(s > 0):
        v = 0.0 if np.any(s > 0) else math.inf  # the budget covers n_max everywhere (or nothing varies)
    else:
        # total(V) is non-increasing in V: bisect log V between "all n_max" and "all n_min"
        pos = s[s > 0]
        lo = math.log(pos.min() / n_max) - 1.0   # every pixel with s > 0 above n_max
        hi = math.log(pos.max() / n_min) + 1.0   # every pixel at n_min
        s_inf = np.where(np.isfinite(s), s, np.inf)   # once, not in each of the 60 steps
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if _n_of(s_inf, math.exp(mid), n_min, n_max, sanitised=True).sum() > total:
                lo = mid
            else:
                hi = mid
        v = math.exp(hi)
    if v == 0.0:
        n_p = np.full((H, W), n_max, np.int64)
    else:
        n_p = _n_of(sig ** power, v, n_min, n_max)
    n_p = np.where(cov, n_p, 0).astype(np.int32)
    # the variance map is a variance of radiance: "relative"'s key sigma2 / (mu^2 + floor^2) has no units (it read the
    # same under a sky 100 times brighter until session 74), so its map is the bound sigma2 over N_p, as the others';
    # "measured"'s is the frame's estimator's (with MIS the step's, not the one-sample key's: 2-4.5x less)
    if allocation == "relative":
        var = buf.sigma2.numpy().reshape(H, W).astype(np.float64)
    elif allocation == "measured" and (est := buf.estimator_variance(mis)) is not key:   # with MIS: the step's
        var = est.numpy().reshape(H, W).astype(np.float64)
    else:
        var = sig
    with np.errstate(divide="ignore", invalid="ignore"):
        variance = np.where(cov & (n_p > 0), var / np.maximum(n_p, 1), 0.0).astype(np.float32)
    planned = int(_n_of(s, v, n_min, n_max).sum()) if v != 0.0 else n_plan * n_max
    stats = {"budget_spp": float(budget), "n_min": int(n_min), "n_max": int(n_max), "allocation": allocation,
             "v_target": v,
             "planned_pixels": n_plan, "planned_samples": planned, "budget_samples": total,
             "over_budget": bool(over)}
    return SampleAllocation(n_p, variance, v, n_plan, planned, total, bool(over), stats)
