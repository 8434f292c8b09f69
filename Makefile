# Two commands set everything up: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
DEMO_DB := demo/demo.duckdb

.PHONY: venv demo test bench golden docs clean

$(BIN)/logiq-sql: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test,sumo,spark,formats]'
	@touch $@

venv: $(BIN)/logiq-sql

demo: venv
	rm -f $(DEMO_DB)
	$(BIN)/logiq-sql ingest commonroad tests/data/commonroad_ngsim --db $(DEMO_DB) --quiet
	$(BIN)/logiq-sql ingest scenarionet tests/data/nuscenes_mini_scenarionet --db $(DEMO_DB) --quiet
	$(BIN)/logiq-sql ingest av2 tests/data/av2 --db $(DEMO_DB) --quiet
	$(BIN)/logiq-sql match --db $(DEMO_DB) --out demo/out
	@echo; echo "Closest followers (NGSIM: every car is the SUT in turn):"
	@$(BIN)/logiq-sql query --db $(DEMO_DB) --limit 8 "select m.drive_id, m.ego_id, m.actor_id, round(m.start_s, 1) as start_s, round(m.end_s, 1) as end_s, \
	  round(k.ego_avg_speed_mph, 1) as ego_avg_speed_mph, round(k.ego_min_distance_to_vehicle_m, 3) as min_gap_m, \
	  round(k.ego_min_ttc_to_vehicle_s, 3) as min_ttc_s \
	  from matches m join kpis k using (match_id) where m.scenario = 'follower_vehicle' order by min_gap_m limit 8"
	@echo; echo "Coverage of follower_vehicle, ego_speed_at_start (mph):"
	@$(BIN)/logiq-sql query --db $(DEMO_DB) "select bucket, hits from coverage where scenario = 'follower_vehicle' \
	  and item = 'ego_speed_at_start' order by bucket_index nulls last"
	@echo; echo "Ego cut-outs (sut_cut_out), with both phases and the coverage sampled at the lane change:"
	@$(BIN)/logiq-sql query --db $(DEMO_DB) --limit 6 "select m.drive_id, m.ego_id, m.actor_id, \
	  round(max(case when p.phase_index = 1 then p.start_s end), 1) as follow_from_s, \
	  round(max(case when p.phase_index = 2 then p.start_s end), 1) as lane_change_s, round(m.end_s, 1) as end_s, \
	  round(k.speed_at_change_lane_kph, 1) as npc_kph, round(k.distance_at_change_lane_m, 1) as gap_m, \
	  k.side_of_npc_relative_to_ego_at_lane_change as npc_side \
	  from matches m join match_phases p using (match_id) join kpis k using (match_id) \
	  where m.scenario = 'sut_cut_out' group by all order by m.drive_id, m.ego_id limit 6"
	@echo; echo "Cyclist matches (nuScenes); the closest moving cyclist of the bundled scenes passes 5.2 m away:"
	@$(BIN)/logiq-sql match --db $(DEMO_DB) --scenario cyclist_close_to_moving_sut --set max_distance_from_cyclist=6m --quiet
	@echo; echo "Unprotected left turn: none in the real drives. Why not, for the Argoverse 2 Miami ego, which stops in a"
	@echo "junction while an oncoming car passes (logiq-sql explain; AV2 maps have no traffic lights):"
	@$(BIN)/logiq-sql explain --db $(DEMO_DB) --scenario unprotected_left_turn_with_yield_and_traffic_light \
	  --drive 3b3570b4-7b0b-3268-a571-b0889dbf40b6 --ego recorded --actor 2357dba4-c8f6-40e7-aee3-6af6a2908521
	@echo; echo "The same scenario on a simulated signalised junction (SUMO, 5 min, bundled; signal states known):"
	rm -f demo/sumo.duckdb
	$(BIN)/logiq-sql ingest sumo tests/data/sumo/junction_s1 --db demo/sumo.duckdb --quiet
	$(BIN)/logiq-sql match --db demo/sumo.duckdb --scenario unprotected_left_turn_with_yield_and_traffic_light --ego every:3 --quiet
	@$(BIN)/logiq-sql query --db demo/sumo.duckdb --limit 6 "select m.ego_id, m.actor_id, round(m.start_s, 1) as start_s, \
	  string_agg(round(p.end_s - p.start_s + 0.1, 1)::varchar, ' + ' order by p.phase_index) as phase_seconds, \
	  k.traversal_relative_direction as traversal, round(k.pet_between_sut_and_npc_s, 2) as pet_s \
	  from matches m join match_phases p using (match_id) join kpis k using (match_id) group by all \
	  order by start_s limit 6"
	$(BIN)/logiq-sql report --db $(DEMO_DB) --out demo/report.html
	@echo; echo "Drives: $(DEMO_DB) (tables documented in docs/tables.md); Parquet in demo/out/; report in demo/report.html"
	@$(BIN)/logiq-sql query --db $(DEMO_DB) "select status, count(*) as drives, cast(sum(matches) as bigint) as matches from drives group by 1"

# two workers (pytest-xdist), one test file each at a time: TEST_WORKERS=0 runs the suite in this process
TEST_WORKERS ?= 2
test: venv
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder

TIER ?= S
bench: venv
	$(BIN)/python -m benchmarks.tiers --tier $(TIER) $(BENCH_ARGS)
	$(BIN)/python -m benchmarks.components --tier $(TIER) --kept

# after a deliberate change of meaning only (its own commit): the bundled-drive goldens and tier S's
golden: venv
	$(BIN)/python -m tests.golden --write
	$(BIN)/python -m benchmarks.tiers --tier S --no-baseline --write-golden

docs: venv
	$(BIN)/python -m logiq_sql.storage.docs

clean:
	rm -rf $(VENV) demo build dist .pytest_cache
