pub fn import_yaml(_t:&str,n:&str)->crate::Result<super::SystemSpec>{Err(crate::Error::spec(n,"yaml import not yet"))}
