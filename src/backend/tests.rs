//! The backend's device rules.

use super::*;

#[test]
fn auto_places_a_stage_on_an_adapter_only_where_a_record_says_it_is_faster() {
    // The project's records: TV, stereo and meshing on hardware GPUs, nothing on lavapipe.
    let hw = GpuStages::auto_rule(AdapterClass::Hardware, RECORDED_FASTER);
    assert_eq!(
        (hw.fusion, hw.tv, hw.stereo, hw.mesh),
        (false, true, true, true)
    );
    assert_eq!(hw, GpuStages::MEASURED_FASTER);
    assert!(!GpuStages::auto_rule(AdapterClass::Software, RECORDED_FASTER).any());
    // A fake table: fusion and meshing faster on hardware, stereo faster on a software
    // adapter.
    let fake = [
        StageRecord {
            stage: Stage::Fusion,
            class: AdapterClass::Hardware,
            record: "fake",
        },
        StageRecord {
            stage: Stage::Mesh,
            class: AdapterClass::Hardware,
            record: "fake",
        },
        StageRecord {
            stage: Stage::Stereo,
            class: AdapterClass::Software,
            record: "fake",
        },
    ];
    let hw = GpuStages::auto_rule(AdapterClass::Hardware, &fake);
    assert_eq!(
        (hw.fusion, hw.tv, hw.stereo, hw.mesh),
        (true, false, false, true)
    );
    assert_eq!(hw.describe(), "fusion and meshing");
    let sw = GpuStages::auto_rule(AdapterClass::Software, &fake);
    assert_eq!(
        (sw.fusion, sw.tv, sw.stereo, sw.mesh),
        (false, false, true, false)
    );
    // No record: the CPU for every stage.
    assert!(!GpuStages::auto_rule(AdapterClass::Hardware, &[]).any());
    assert_eq!(
        GpuStages::ALL.describe(),
        "fusion and TV and stereo and meshing"
    );
}
