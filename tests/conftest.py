import os
import shutil
import sys
import tempfile
import zlib
from pathlib import Path

import jax
import numpy as np
import pytest

# The repository root holds numpy_ref (the numpy references shared with the benchmarks, not part of
# the library): importable however pytest was started, in xdist workers too.
ROOT = str(Path(__file__).resolve().parents[1])
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

#: The ``make check`` tier: per test file, the tests that run in it (every parametrization of
#: each). One or a few quick tests per file, so that the tier touches every module of the
#: library in a few minutes; ``make test`` runs everything.
CHECK_TIER = {
    "test_import_graph.py": ("test_no_module_imports_another_modules_private_names", "test_import_graph_has_no_cycles"),
    "test_maps.py": ("test_noise_free_map_is_exact", "test_cli_fit_map"),
    "test_capture.py": ("test_round_trip_directions", "test_round_trip_positions"),
    "test_diffuse_specular.py": ("test_eval_and_pdf_match_reference", "test_bad_parameters_raise"),
    "test_docstrings.py": ("test_the_catalogue_is_not_empty",),
    "test_export.py": ("test_exact_mitsuba_exports_evaluate_equal_in_mitsuba", "test_pbrt_lines_parse_and_carry_alpha_without_remapping"),
    "test_render.py": ("test_lambert_white_renders_one_everywhere_in_the_furnace", "test_only_what_the_scene_calls_for_is_computed"),
    "test_bad_input.py": ("test_albedo_method", "test_channel_counts_must_match"),
    "test_cache.py": ("test_second_process_loads_compiled_programs", "test_loop_jit_keeps_table_only_work_inside_the_loop"),
    "test_compile_count.py": ("test_counter_sees_a_compilation", "test_jitted_eval_compiles_once"),
    "test_conductor_guess.py": ("test_initial_guess_uses_fresnel_curve",),
    "test_fast.py": ("test_channel_model_slices_per_channel_parameters_only", "test_isotropic_distributions_read_only_cosines"),
    "test_fit_lm_fd.py": ("test_lm_fd_reaches_scipy_loss",),
    "test_fit_measured.py": ("test_split_is_the_documented_disjoint_80_20_split", "test_padding_fixes_the_shape_and_changes_no_fit"),
    "test_fresnel.py": ("test_average_vs_quadrature", "test_dielectric_inside_vs_colour"),
    "test_thin_film.py": ("test_spectrum_matches_the_characteristic_matrix", "test_bad_parameters_raise"),
    "test_sheen.py": ("test_eval_matches_reference", "test_bad_parameters_raise"),
    "test_hard_cases.py": ("test_smooth_dielectric_total_internal_reflection", "test_blinn_phong_alpha_above_one_raises",
                           "test_property_rough_conductor"),
    "test_io_alta.py": ("test_minimal_cos_th", "test_pink_felt_slice"),
    "test_io_errors.py": ("test_rgl_malformed_bytes", "test_fuzz_random_bytes_all_readers"),
    "test_io_merl.py": ("test_lookup_reciprocal_and_horizon", "test_round_trip_bit_exact"),
    "test_io_rgl.py": ("test_warp_sample_invert_consistent", "test_albedo_bounded"),
    "test_layered.py": ("test_dtypes_finite",),
    "test_lm_split.py": ("test_gram_equals_numpy", "test_split_residuals_equal_interleaved"),
    "test_loss_history.py": ("test_bad_method",),
    "test_losses.py": ("test_residuals_match_reference",),
    "test_measured_models.py": ("test_rgl_eval_matches_the_reader", "test_bad_input_raises_clear_errors"),
    "test_low2012.py": ("test_parse_published_fits", "test_published_D_is_unnormalized_beckmann"),
    "test_published_fits.py": ("test_direction_form_matches_angle_form", "test_loader_covers_every_row"),
    "test_published_values.py": ("test_low_smooth_retro_integral",),
    "test_mcmc.py": ("test_log_prob_matches_numpy",),
    "test_model_tables.py": ("test_tables_are_up_to_date",),
    "test_multi_lobe.py": ("test_eval_and_pdf_match_reference", "test_composed_families_layout"),
    "test_reciprocity_gradients.py": ("test_rough_conductor_reciprocity",),
    "test_reference_agreement.py": ("test_G2",),
    "test_report_cli.py": ("test_cli_fit_npz_with_report",),
    "test_sampling.py": ("test_smooth_dielectric",),
    "test_stable_fits.py": ("test_black_table_flags_bound", "test_masked_rows_do_not_influence_the_fit"),
    "test_starts.py": ("test_initial_guesses_batch_equals_one_by_one",),
    "test_stochastic_layered.py": ("test_eval_matches_exact_analytic_smooth_coat",),
    "test_synth.py": ("test_shipped_scenes_parse", "test_cli_synth_info_roundtrip"),
    "test_table.py": ("test_as_jax",),
    "test_appearance.py": ("test_flip_of_uniform_images_is_the_papers_colour_difference",
                           "test_ciede2000_on_sharmas_test_pairs", "test_white_lambertian_sphere_in_the_furnace_renders_one"),
    "test_choose.py": ("test_cues_see_what_the_material_shows",),
    "test_tabulated_ndf.py": ("test_tabulated_ggx_matches_reference", "test_extraction_power_iteration_and_two_lobes"),
}


def pytest_configure(config):
    # float64 is on for the whole session, switched once here (float32 tests pass float32
    # arrays and parameters explicitly); no test module switches it at import
    jax.config.update("jax_enable_x64", True)
    # the CLI switches JAX's persistent compilation cache on; in-process CLI tests must neither
    # write into the user's cache nor change how the rest of the session compiles
    # (tests/test_cache.py tests the cache in subprocesses of its own)
    os.environ["MATFIT_NO_CACHE"] = "1"
    # one JAX persistent compilation cache for the session, in a fresh folder shared by the xdist
    # workers: a program that both workers (or two tests building the same program afresh)
    # compile is compiled once and loaded after; removed when the session ends
    folder = os.environ.get("MATFIT_TEST_JAX_CACHE")
    if folder is None:
        folder = tempfile.mkdtemp(prefix="matfit-test-jax-")
        os.environ["MATFIT_TEST_JAX_CACHE"] = folder  # inherited by the workers, started after this
        config._matfit_cache_owner = folder
    jax.config.update("jax_compilation_cache_dir", folder)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    config.addinivalue_line("markers", "check: the quick `make check` tier (see CHECK_TIER in tests/conftest.py)")


def pytest_unconfigure(config):
    folder = getattr(config, "_matfit_cache_owner", None)
    if folder:
        shutil.rmtree(folder, ignore_errors=True)


#: Memory mappings of a worker above which its compiled programs are dropped (the kernel's limit,
#: ``vm.max_map_count``, is 65,530 here).
MAPPINGS_CLEAR = 25_000


def _mappings():
    try:
        with open("/proc/self/maps", "rb") as f:
            return sum(1 for _ in f)
    except OSError:
        return MAPPINGS_CLEAR + 1  # unknown: always release


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop JAX's in-memory compiled programs after every test module. Each XLA CPU executable
    holds memory mappings, and a worker that kept every program of its share of the suite came
    within a few thousand of the kernel's limit (``vm.max_map_count``, 65,530: 52,490 mappings
    late in a run); past it XLA's compiler cannot map code and the worker dies of a segfault.
    A program needed again is loaded from the session's persistent cache (above)."""
    yield
    if os.environ.get("MATFIT_CLEAR_ALWAYS") or _mappings() > MAPPINGS_CLEAR:
        jax.clear_caches()


@pytest.fixture(autouse=True, scope="module")
def _x64_stays_on(request):
    """The session runs in float64 (``pytest_configure``); a module that switches it off would run
    every later module of its worker in float32 unnoticed (test_conductor_guess.py once did)."""
    yield
    if not jax.config.read("jax_enable_x64"):
        jax.config.update("jax_enable_x64", True)
        pytest.fail(f"{request.module.__name__} left jax_enable_x64 off for the modules after it")


def pytest_collection_modifyitems(config, items):
    from _pytest.doctest import DoctestItem

    for item in items:
        name = getattr(item, "originalname", None) or item.name.split("[")[0]
        # the library's doctests belong to the quick tier as well (one pytest run for make check)
        if isinstance(item, DoctestItem) or name in CHECK_TIER.get(Path(str(item.fspath)).name, ()):
            item.add_marker(pytest.mark.check)


# --- dtype / rng fixtures (reference-agreement helper) -------------------------------------------
# x64 is switched on by the `dtype` fixture and stays on for the rest of the session; float32 tests
# therefore pass explicit float32 arrays (inputs and parameters) to the library.
@pytest.fixture(params=[np.float32, np.float64], ids=["f32", "f64"])
def dtype(request):
    jax.config.update("jax_enable_x64", True)
    return request.param


@pytest.fixture
def rng(request):
    """A numpy Generator seeded from the test id (reproducible, different per test)."""
    seed = zlib.crc32(request.node.nodeid.encode())
    return np.random.default_rng(seed)


@pytest.fixture
def x64():
    """Enable float64 in JAX (for float64-only tests that do not use `dtype`)."""
    jax.config.update("jax_enable_x64", True)
    return np.float64
