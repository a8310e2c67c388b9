//! `[model] kind = "expression"`: each observable's prediction η(x, θ) is a
//! formula of the input x, the parameters θ and constants.

use super::declaration::{check_parameters_used, corners, describe, Declared, Variables};
use crate::engine::formula::Formula;
use crate::engine::model::Simulator;
use anyhow::{bail, Result};

pub struct ExpressionModel {
    parameters: Vec<String>,
    observables: Vec<String>,
    formulas: Vec<Formula>,
    /// Where each formula was written (file, table, key), for errors.
    places: Vec<String>,
    variables: Variables,
    bounds: Vec<(f64, f64)>,
}

impl ExpressionModel {
    pub fn compile(file: &str, d: &Declared) -> Result<ExpressionModel> {
        let variables = Variables::of(file, d)?;
        let scope = variables.scope(variables.state_at);
        let formulas =
            d.observables.iter().map(|(_, w)| Formula::parse(&w.text, &scope, &w.place)).collect::<Result<Vec<_>>>()?;
        check_parameters_used(file, d, &formulas.iter().collect::<Vec<_>>())?;
        Ok(ExpressionModel {
            parameters: d.parameters.clone(),
            observables: d.observables.iter().map(|(o, _)| o.clone()).collect(),
            formulas,
            places: d.observables.iter().map(|(_, w)| w.place.clone()).collect(),
            variables,
            bounds: d.bounds.clone(),
        })
    }
}

impl Simulator for ExpressionModel {
    fn parameter_names(&self) -> Vec<String> {
        self.parameters.clone()
    }

    fn observable_names(&self) -> Vec<String> {
        self.observables.clone()
    }

    fn predict(&self, observable: usize, x: &[f64], theta: &[f64], out: &mut [f64]) {
        let formula = &self.formulas[observable];
        let mut v = self.variables.at(theta);
        for (o, &xi) in out.iter_mut().zip(x) {
            v[0] = xi;
            *o = formula.eval(&v);
        }
    }

    /// The formula must be finite at every data point at every corner of the
    /// prior box (and its centre): a division by zero there is a declaration
    /// error, not something to sample around.
    fn check_inputs(&self, observable: usize, x: &[f64]) -> Result<()> {
        let formula = &self.formulas[observable];
        for theta in corners(&self.bounds) {
            let mut v = self.variables.at(&theta);
            for &xi in x {
                v[0] = xi;
                if !formula.eval(&v).is_finite() {
                    bail!(
                        "{} = {:?} is not finite at x = {xi} with {} (a corner or the centre of the prior box): a division by zero or a function outside its domain; narrow the prior or rewrite the formula",
                        self.places[observable],
                        formula.text(),
                        describe(&self.parameters, &theta)
                    );
                }
            }
        }
        Ok(())
    }
}
