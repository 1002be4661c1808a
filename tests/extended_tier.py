"""The extended tier of the suite's files beyond the two matrices (``make test-extended``).

A fresh machine compiles every kernel anew (about 0.4 s of LLVM time each, a render 5 to
49 of them), so the whole suite takes more than an hour there; ``make test`` must take 20
minutes. The default tier keeps:

- the tests of the tests (a deliberately wrong integrator, parameter or scene fails) of
  every test that runs there, at least one case of each; every refusal and every check of
  bad input;
- every crash, abort and leak regression (the textured mesh light, the gaps over lamps, the
  light behind a panel, the two-thread worker, the killed worker);
- at least one case of every parametrized test, so that every behaviour a test names is
  checked in every run: the furnace and constant-radiance cases of each integrator, one
  integrator of each test run over several;
- the analytic values, the displays' exactness, the walkthrough and the browser page.

The tests and cases below run in the extended tier only: further cases of a test whose
other cases run in every run (FURTHER_CASES), and whole tests whose subject a test of the
default tier also checks, or which are studies of accuracy rather than checks of a
behaviour (SLOW_TESTS). The coverage matrix and the conformance suite choose their cells
by rule in tests/test_coverage.py and tests/test_conformance.py.
"""

#: {"file::test": the ids of its cases in the extended tier}; its other cases run in every run
FURTHER_CASES = {
    "test_configs.py::test_xml_loads_and_renders_its_exact_value": (
        "bekaert_sierpinski", "bekaert_sphere", "constant_brdf_phong_box", "constant_brdf_roughconductor_box",
        "constant_lightsource_box", "constant_lightsource_sierpinski", "diffuse_sphere_mesh", "furnace_box",
        "furnace_sphere", "furnace_sphere_mesh", "mirror_sphere", "mirror_sphere_cos4",
        "sierpinski_diffuse_simulated", "sierpinski_phong_simulated"),
    "test_conformance.py::test_same_seed_gives_the_same_image": (
        "qmc_lighttrace(display=baked)", "qmc_lighttrace(display=patches)", "qmc_lighttrace",
        "ray_bundle(display=baked)", "ray_bundle"),
    "test_constant_radiance.py::test_builtin_integrators_see_constant_radiance": (
        "diffuse-box-ptracer", "diffuse-box-volpath", "diffuse-sphere_mesh-ptracer", "diffuse-sphere_mesh-volpath",
        "phong-sierpinski-ptracer", "phong-sierpinski-volpath", "phong-sphere-ptracer", "phong-sphere-volpath",
        "roughconductor-box-ptracer", "roughconductor-box-volpath", "roughconductor-sierpinski-ptracer",
        "roughconductor-sierpinski-volpath", "roughplastic-sierpinski-ptracer", "roughplastic-sierpinski-volpath",
        "roughplastic-sphere_mesh-ptracer", "roughplastic-sphere_mesh-volpath"),
    "test_constant_radiance.py::test_lightsource_testing_cases": (
        "constant_lightsource_box-ptracer", "constant_lightsource_box-volpath",
        "constant_lightsource_sierpinski-ptracer", "constant_lightsource_sierpinski-volpath"),
    "test_core.py::test_integrators_pass_with_a_low_discrepancy_sampler": (
        "ray_bundle-halton", "stochastic_ray-sobol"),
    "test_core.py::test_the_films_reconstruction_filter_is_used": (
        "ray_bundle",),
    "test_core.py::test_the_scene_sampler_drives_the_camera_samples": (
        "qmc_lighttrace", "ray_bundle"),
    "test_darkness.py::test_the_smooth_field_does_not_cross_the_panel": (
        "ray_bundle",),
    "test_direct_sampling.py::test_smooth_display_stays_bounded_at_emitting_edges": (
        "ray_bundle",),
    "test_distributed.py::test_several_shapes_keep_their_patches_on_every_worker": (
        "ray_bundle",),
    "test_distributed.py::test_the_image_does_not_depend_on_the_number_of_workers": (
        "path", "qmc_lighttrace", "ray_bundle"),
    "test_distributed.py::test_views_share_one_solve_shipped_to_every_worker": (
        "qmc_lighttrace",),
    "test_distributed_threads.py::test_a_two_thread_worker_gives_the_single_thread_image": (
        "ray_bundle",),
    "test_emitter_samples.py::test_a_wrong_share_is_caught": (
        "gaussian",),
    "test_emitter_samples.py::test_the_mean_stays_and_the_edges_quieten": (
        "box-False-gather", "box-False-smooth", "box-True-smooth"),
    "test_gaps.py::test_the_light_trapped_over_the_lamp_does_not_leak": (
        "smooth",),
    "test_garbage.py::test_a_render_leaves_no_cycle_holding_plugins_or_arrays": (
        "qmc_lighttrace-smooth-refine-preview", "qmc_lighttrace", "ray_bundle-smooth-refine-preview", "ray_bundle"),
    "test_garbage.py::test_a_scene_without_dark_splits_leaves_no_cycle": (
        "ray_bundle",),
    "test_gradients.py::test_mitsuba_gradients_pass": (
        "diffuse_sphere-albedo-integrator2-32-forward", "furnace_sierpinski-albedo-integrator1-128-reverse",
        "mirror_sphere-reflectance-integrator5-32-forward", "mirror_sphere_cos4-reflectance-integrator7-32-forward",
        "mirror_sphere_cos4-reflectance-integrator8-32-reverse"),
    "test_harness.py::test_mitsuba_integrators_pass_every_case": (
        "bekaert_box-ptracer", "bekaert_sierpinski-path", "bekaert_sphere-path", "bekaert_sphere-ptracer",
        "diffuse_sphere-ptracer", "diffuse_sphere_mesh-path", "furnace_box-path", "furnace_box-ptracer",
        "furnace_sierpinski-ptracer", "furnace_sphere-path", "furnace_sphere_mesh-path",
        "furnace_sphere_mesh-ptracer", "keller_cube-ptracer", "mirror_sphere-path", "mirror_sphere_cos4-path"),
    "test_meshtable.py::test_the_finite_element_integrators_refuse_them": (
        "ray_bundle",),
    "test_meshtable.py::test_vertex_normals_against_the_winding_are_refused": (
        "ray_bundle",),
    "test_padded_samplers.py::test_finding_stratified_sampler_biases_path_on_the_furnace": (
        "stratified-36-1000-False",),
    "test_padded_samplers.py::test_package_samplers_are_unbiased": (
        "cmj-4", "cmj-64", "faure-4", "faure-64", "halton-4", "halton-64", "lattice-4", "lattice-64",
        "padded_sobol-4", "padded_sobol-64", "sobol-4", "sobol-64", "zsobol-4", "zsobol-64"),
    "test_qmc_lighttrace.py::test_closed_walls_let_no_light_through": (
        "constant",),
    "test_qmc_lighttrace.py::test_direct_light_of_environment_and_delta_lights_matches_path": (
        "constant", "envmap", "point", "spot"),
    "test_qmc_lighttrace.py::test_emission_cases_match_path": (
        "case:light_facing_ceiling-64-1024-16", "package:simulated_area-32-256-8"),
    "test_qmc_lighttrace.py::test_every_max_depth_matches_path": (
        "2", "3"),
    "test_qmc_lighttrace.py::test_keller_cube_exact_truncated_value": (
        "independent", "lcg", "sobol", "faure"),
    "test_qmc_lighttrace.py::test_non_diffuse_bsdfs_match_path": (
        "phong", "plastic", "roughconductor", "roughplastic", "bumpmap", "mask", "blendbsdf"),
    "test_qmc_lighttrace.py::test_particles_carry_the_power_of_every_emitter_type": (
        "constant", "directional", "envmap"),
    "test_qmc_lighttrace.py::test_particles_choose_lobe_and_direction_with_independent_numbers": (
        "phong",),
    "test_qmc_lighttrace.py::test_unbounded_cases": (
        "bekaert_sierpinski", "diffuse_sphere_mesh", "sierpinski_diffuse_simulated"),
    "test_ray_bundle.py::test_analytic_cases": (
        "bekaert_sierpinski", "constant_brdf_phong_box", "diffuse_sphere", "diffuse_sphere_mesh",
        "furnace_sphere_mesh", "sierpinski_diffuse_simulated", "sierpinski_phong_simulated"),
    "test_ray_bundle.py::test_average_diffuse_analytic_cases": (
        "bekaert_sierpinski-fs-no_nee", "bekaert_sierpinski", "constant_brdf_phong_box-fs",
        "constant_lightsource_box", "furnace_sphere_mesh-fs", "diffuse_sphere_mesh-fs",
        "sierpinski_diffuse_simulated-fs", "constant_lightsource_box-fs-no_nee"),
    "test_ray_bundle.py::test_average_diffuse_variants_pass_the_furnace": (
        "patch-fs-one_way", "patch"),
    "test_ray_bundle.py::test_curved_patches_evaluated_where_they_face_away_fail": (
        "furnace_cylinder",),
    "test_ray_bundle.py::test_curved_patches_keep_their_power": (
        "furnace_cylinder",),
    "test_ray_bundle.py::test_first_shot_analytic_cases": (
        "constant_brdf_phong_box", "constant_lightsource_box", "furnace_sphere_mesh", "diffuse_sphere_mesh",
        "sierpinski_diffuse_simulated"),
    "test_ray_bundle.py::test_max_depth_truncates_as_path_does": (
        "1", "5"),
    "test_ray_bundle.py::test_variants_pass_the_furnace": (
        "first_shot-patch", "independent-one_way", "one_way", "pi"),
    "test_ray_bundle.py::test_wrong_images_fail": (
        "patch",),
    "test_refinement.py::test_previews_show_the_refined_patches": (
        "ray_bundle",),
    "test_refinement.py::test_refined_patches_keep_constant_radiance_exact": (
        "gather", "smooth"),
    "test_residual.py::test_the_residual_check_removes_the_smooth_display_bias_beside_the_strip": (
        "ray_bundle",),
    "test_rough_glass.py::test_light_tracers_match_path_with_rough_glass_lit_from_inside": (
        "qmc_lighttrace:smooth", "stochastic_ray"),
    "test_samplers.py::test_builtin_integrators_with_qmc_samplers_pass": (
        "bekaert_sierpinski-path-sobol", "bekaert_sierpinski-prb-cmj", "bekaert_sierpinski-prb-faure",
        "bekaert_sierpinski-prb-lattice", "bekaert_sierpinski-prb-padded_sobol", "bekaert_sierpinski-prb-sobol",
        "bekaert_sierpinski-prb-zsobol", "bekaert_sierpinski-ptracer-cmj", "bekaert_sierpinski-ptracer-faure",
        "bekaert_sierpinski-ptracer-halton", "bekaert_sierpinski-ptracer-lattice",
        "bekaert_sierpinski-ptracer-padded_sobol", "bekaert_sierpinski-ptracer-zsobol",
        "bekaert_sierpinski-volpath-halton", "bekaert_sierpinski-volpath-sobol",
        "sierpinski_phong_simulated-path-faure", "sierpinski_phong_simulated-path-halton",
        "sierpinski_phong_simulated-path-sobol", "sierpinski_phong_simulated-volpath-faure",
        "sierpinski_phong_simulated-volpath-halton", "sierpinski_phong_simulated-volpath-sobol"),
    "test_setup_cache.py::test_a_scene_rendered_again_takes_its_setup_from_the_cache": (
        "qmc_lighttrace",),
    "test_solution.py::test_a_solution_is_kept_for_its_scene_and_seed": (
        "ray_bundle",),
    "test_solution.py::test_a_solution_serves_its_scene_loaded_again_in_another_order": (
        "ray_bundle",),
    "test_solution.py::test_a_wrong_solution_fails_the_constant_radiance_check": (
        "ray_bundle",),
    "test_solution.py::test_clustered_patches_are_exact_in_the_furnace": (
        "qmc_lighttrace-gather", "ray_bundle-smooth", "ray_bundle-gather"),
    "test_solution.py::test_displays_are_exact_in_constant_radiance_scenes": (
        "furnace-ray_bundle", "keller_cube-qmc_lighttrace", "keller_cube-ray_bundle"),
    "test_solution.py::test_displays_of_the_bundles_that_carry_the_direct_light": (
        "baked", "patches"),
    "test_solution.py::test_previews_show_the_solution_as_it_goes": (
        "ray_bundle",),
    "test_solution.py::test_solves_on_the_same_patches_share_their_field": (
        "ray_bundle",),
    "test_steep.py::test_the_displays_show_no_negative_light_beside_the_strip": (
        "smooth-True",),
    "test_stochastic_ray.py::test_analytic_cases": (
        "bekaert_sierpinski", "constant_brdf_diffuse_sphere", "constant_brdf_phong_box",
        "constant_lightsource_sierpinski", "sierpinski_phong_simulated", "diffuse_sphere", "bekaert_box"),
    "test_stochastic_ray.py::test_truncated_depths": (
        "1", "3"),
    "test_textured_lights.py::test_a_checkerboard_light_among_other_emitters": (
        "stochastic_ray",),
    "test_textured_lights.py::test_a_wrongly_sampled_light_behind_a_handoff_is_refused": (
        "ray_bundle",),
    "test_textured_lights.py::test_qmc_lighttrace_on_a_flipped_textured_light": (
        "checkerboard",),
}

#: {"file::test": what checks its subject in every run, or why it is a study}
SLOW_TESTS = {
    "test_cli.py::test_verify_rows_of_the_package_integrators_pass":
        "the installed wheel's verify run (tests/test_wheel.py) and the analytic tests of each integrator",
    "test_conformance.py::test_display_cells_render_the_smooth_cells_solves":
        "the conformance display cells of every run render the smooth cells' solves",
    "test_core.py::test_light_splats_with_a_wide_filter_and_a_crop_window_stay_unbiased":
        "the coverage rows of filters and crop windows (extended) and the films' filter test",
    "test_crowding.py::test_the_smooth_display_along_the_shelf_and_the_block":
        "a study of the smooth display's error at crowded patches; the gap cells check the crowding",
    "test_darkness.py::test_the_patches_display_is_right_where_the_floor_and_ceiling_cross_the_wall":
        "the dark-split tests of every run (the light behind a panel, the smooth field at the panel)",
    "test_demo.py::test_demo_writes_every_image_with_its_errors":
        "the installed wheel runs mi-plugins demo (tests/test_wheel.py)",
    "test_direct_sampling.py::test_light_sample_alone_far_from_emitters_keeps_the_mean":
        "the emitting-edge test of the same file",
    "test_distributed.py::test_a_killed_worker_loses_nothing":
        "the lone killed worker's test",
    "test_distributed.py::test_cli_renders_every_sensor":
        "the command line's render with workers",
    "test_distributed.py::test_ray_bundle_splits_its_chains_and_its_final_gathering":
        "the worker-count tests and ray_bundle's chain tests",
    "test_emitter_samples.py::test_ray_bundle_gather_takes_them_in_its_frozen_camera_pass":
        "the emitter-sample tests of the gathers and displays",
    "test_emitter_samples.py::test_ray_bundle_records_its_camera_pass_once_with_emitter_samples":
        "the no-recompilation tests (tests/test_kernels.py)",
    "test_findings.py::test_flip_normals_reproducer_runs_and_still_reproduces":
        "a Mitsuba finding's reproducer: it tracks Mitsuba, not the package",
    "test_findings.py::test_roughdielectric_reproducer_runs_and_still_reproduces":
        "a Mitsuba finding's reproducer: it tracks Mitsuba, not the package",
    "test_gaps.py::test_a_display_does_not_show_the_mouths_averages":
        "the gap tests of every run (the light trapped over the lamp)",
    "test_padded_samplers.py::test_verify_matrix_runs_every_mitsuba_sampler_with_every_mitsuba_integrator":
        "the sampler tests of every run; this one runs Mitsuba's own integrators",
    "test_qmc_lighttrace.py::test_a_bright_room_keeps_a_finite_variance":
        "a study of the variance in an albedo-0.9 room",
    "test_qmc_lighttrace.py::test_masked_floor_and_box_of_the_cornell_box_match_volpath":
        "the mask regression row of the coverage matrix",
    "test_qmc_lighttrace.py::test_neighbour_sharing_passes_and_lowers_the_error":
        "a study of the error with neighbour sharing",
    "test_qmc_lighttrace.py::test_scramble_false_is_deterministic_and_passes":
        "the same-seed tests of the conformance suite",
    "test_qmc_lighttrace.py::test_the_display_modes_trace_paths_by_the_patch_count":
        "the displays' exactness tests",
    "test_qmc_lighttrace.py::test_two_sided_walls_seen_from_behind_match_path":
        "the conformance suite's two-sided scene",
    "test_ray_bundle.py::test_chains_are_independent_and_averaged":
        "the analytic cases and the worker-count tests",
    "test_ray_bundle.py::test_chains_share_their_diffuse_patches":
        "the analytic cases",
    "test_ray_bundle.py::test_subdivided_patches_stay_exact":
        "qmc_lighttrace's subdivided cube and the refinement tests",
    "test_solution.py::test_every_sensor_and_a_camera_path_from_one_solve":
        "the walkthrough test (tests/test_walkthrough.py)",
    "test_solution.py::test_ray_bundle_previews_begin_in_the_burn_in_and_leave_the_solution_as_it_was":
        "the previews tests",
    "test_steep.py::test_steep_patches_are_decided_on_a_second_solve":
        "a study of the smooth display beside a lit strip; the negative-light test runs",
    "test_steep.py::test_steep_patches_gather_beside_the_lit_strip":
        "a study of the smooth display beside a lit strip; the negative-light test runs",
    "test_steep.py::test_the_default_smooth_display_beside_the_lit_strip":
        "a study of the smooth display beside a lit strip; the negative-light test runs",
    "test_steep.py::test_the_limited_smooth_display_beside_the_lit_strip":
        "a study of the smooth display beside a lit strip; the negative-light test runs",
    "test_stochastic_ray.py::test_hide_emitters":
        "the hide_emitters row of the coverage matrix",
    "test_textured_lights.py::test_qmc_lighttrace_on_a_textured_light_with_uv_seams":
        "the textured-light tests of every run",
    "test_ray_bundle.py::test_lines_do_not_skip_a_lamp_just_under_the_ceiling":
        "the lamp facing a ceiling 1 cm above (test_lamp_facing_a_ceiling_1cm_above)",
    "test_ray_bundle.py::test_a_coarse_line_offset_would_skip_the_lamp":
        "the test of the test beside it, which is extended with it",
    "test_ray_bundle.py::test_diffuse_patches_share_one_direct_light_estimate":
        "ray_bundle's analytic cases with first_shot",
    "test_ray_bundle.py::test_gather_nee_splits_a_patch_constant_radiance":
        "ray_bundle's analytic cases and the refinement tests",
    "test_ray_bundle.py::test_first_shot_halves_the_error":
        "a study of the error with first_shot",
    "test_ray_bundle.py::test_average_diffuse_lowers_the_error":
        "a study of the error with average_diffuse",
    "test_ray_bundle.py::test_sky_light_is_not_mistaken_for_unconverged_interreflection":
        "the conformance suite's skies and ray_bundle's burn-in tests",
    "test_ray_bundle.py::test_alpha_is_the_cameras_coverage":
        "the coverage matrix's alpha regression row (format:rgba)",
    "test_ray_bundle.py::test_hide_emitters_passes_camera_rays_through_emitters":
        "the coverage matrix's hide_emitters row",
    "test_emitter_samples.py::test_other_cameras_and_films_keep_the_mean":
        "the other emitter-sample tests and the coverage matrix's sensor and film rows",
    "test_stochastic_ray.py::test_the_bright_furnace_renders_at_the_default_max_iterations":
        "the furnace cases at the default limit; its refusal below the limit runs in every run",
    "test_ray_bundle.py::test_lightsource_sierpinski":
        "stochastic_ray's case of the same scene; a 3.5 % bound, the power rule's documented exception",
    "test_ray_bundle.py::test_hammersley_directions_are_wrong_independent_are_right":
        "a study of the direction sets; the analytic cases check the default",
    "test_ray_bundle.py::test_error_shrinks_like_inverse_sqrt_of_iterations":
        "a convergence-rate study; stochastic_ray's runs in every run",
    "test_ray_bundle.py::test_stratified_chains_lower_the_error":
        "a study of the direction sets; the analytic cases check the default",
    "test_ray_bundle.py::test_albedo_one_room_at_the_defaults_extends_its_burn_in":
        "the refusal of a burn-in beyond max_iterations (113 s on a fresh machine)",
}


def extended(nodeid):
    """True if the test ``nodeid`` (``tests/file::test[case]``) is one of this tier's."""
    path, _, rest = nodeid.partition("::")
    name, _, case = rest.partition("[")
    key = "%s::%s" % (path.rsplit("/", 1)[-1], name)
    return key in SLOW_TESTS or (case and case[:-1] in FURTHER_CASES.get(key, ()))
