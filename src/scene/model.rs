//! The serde model of scene files (`SCENE_FORMAT.md`), shared by RON and JSON.
