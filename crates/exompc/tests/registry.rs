//! The controller registry (`exompc::scenario::CONTROLLERS`): one entry per controller kind,
//! consistent names, and builders that build the controller they name.

use exompc::config::{ControllerKind, Scenario};
use exompc::scenario::{
    build_controller, controller_by_name, controller_info, initial_torque, OneDof, TwoDof,
    CONTROLLERS,
};
use serde::de::value::{Error, StrDeserializer};
use serde::Deserialize;

#[test]
fn every_kind_has_one_entry_with_its_config_name() {
    for kind in [
        ControllerKind::Pd,
        ControllerKind::Nmpc,
        ControllerKind::Msnmpc,
    ] {
        assert_eq!(
            CONTROLLERS.iter().filter(|c| c.kind == kind).count(),
            1,
            "{kind:?}"
        );
        assert_eq!(controller_info(kind).kind, kind);
    }
    for (i, c) in CONTROLLERS.iter().enumerate() {
        // The registry name is the config file's spelling of the kind.
        let parsed = ControllerKind::deserialize(StrDeserializer::<Error>::new(c.name)).unwrap();
        assert_eq!(parsed, c.kind, "{}", c.name);
        assert_eq!(controller_by_name(c.name).map(|d| d.kind), Some(c.kind));
        for d in &CONTROLLERS[..i] {
            assert!(d.name != c.name && d.label != c.label && d.colour != c.colour);
        }
        assert!(!c.description.is_empty());
    }
    assert!(controller_by_name("lqr").is_none());
}

#[test]
fn builders_build_the_controller_they_name() {
    let s = Scenario::default();
    for c in CONTROLLERS {
        let two = (c.build_2dof)(&s, initial_torque::<TwoDof, 2>(&s)).unwrap();
        let one = (c.build_1dof)(&s, initial_torque::<OneDof, 1>(&s)).unwrap();
        assert_eq!(two.name(), c.name);
        assert_eq!(one.name(), c.name);
        assert_eq!(
            build_controller::<TwoDof, 2>(&s, c.kind).unwrap().name(),
            c.name
        );
    }
}
